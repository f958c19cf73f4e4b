"""Resolving the ``--env`` argument: Gymnasium IDs, ``module:EnvId``, and any PettingZoo env.

A PettingZoo env is named by its module (PettingZoo's convention: a module exposing ``parallel_env(**kwargs)``,
such as ``pettingzoo.sisl.pursuit_v5``, ``mpe2.simple_spread_v3`` or ``my_pkg.my_env_v0``), by
``module:callable`` (a function returning a ``ParallelEnv``), or by a short name registered with
:func:`sbagents.registration.register_pettingzoo_env` (``treasure_hunt_v0``). Its run dirs and config entries use
the env's name: the module's last component (``pursuit_v5``, also for ``module:parallel_env`` and a game's
``module:env``), or module and callable (``my_pkg.envs:make_env``, run dirs ``my_pkg.envs_make_env_<k>``), so two
modules' callables of the same name never share run dirs.
"""

from __future__ import annotations

import difflib
import functools
import importlib
import keyword
from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import gymnasium as gym

from sbagents.core.env_kinds import GAME, REGISTERED_KINDS, SINGLE_AGENT, TEAM, EnvKind, builtin_kinds
from sbagents.errors import UsageError
from sbagents.registration import ARRAY_IMPLEMENTATIONS, METRIC_OBSERVERS, PETTINGZOO_ENVS

#: Top-level modules of optional packages -> the sbagents extra that installs them (``pip install 'sbagents[X]'``):
#: a name that needs one of them says which extra to install instead of "unknown env id".
OPTIONAL_MODULES: dict[str, str] = {
    "mpe2": "pettingzoo-envs",
    "pymunk": "pettingzoo-envs",
    "pygame": "pettingzoo-envs",
    "Box2D": "pettingzoo-envs",
    "rlcard": "pettingzoo-envs",
    "envpool": "atari",
    "ray": "distributed",
    "opacus": "private",
    "flwr": "federated",
}


@dataclass(frozen=True)
class EnvRef:
    """A resolved env name.

    :param env_id: canonical id: a Gymnasium ID, or the PettingZoo env's name (``pursuit_v5``).
    :param kind: what kind of env it is (:mod:`sbagents.core.env_kinds`): a Gymnasium env, a PettingZoo team, or
        a turn-based (AEC) game with action masks, trained and evaluated from one seat against opponents.
    :param modules: modules to import before building the env in any process (``--gym-packages``, the ``module``
        of ``module:EnvId``, ``ale_py`` for Atari ids): a worker process starts with none of them imported.
    :param source: where a PettingZoo env comes from: ``pkg.module`` (with ``parallel_env``, or ``env`` for a
        turn-based game) or ``pkg.module:callable``.
    """

    env_id: str
    kind: EnvKind = SINGLE_AGENT
    modules: tuple[str, ...] = ()
    source: str = ""

    @property
    def is_atari(self) -> bool:
        """Whether this is an ALE id (RL Zoo's ``atari`` config entry applies)."""
        return not self.kind.pettingzoo and ("NoFrameskip" in self.env_id or self.env_id.startswith("ALE/"))

    @property
    def config_keys(self) -> tuple[str, ...]:
        """Zoo-config entries to look up, in order (``default`` comes after them)."""
        return self.kind.config_entries(self)

    def trusted_modules(self) -> tuple[str, ...]:
        """The modules the user named for this env (``--gym-packages``, ``--env module:...``, a PettingZoo env's
        module): the classes a run's config or model may name besides sbagents' import allow-list."""
        source = self.source.partition(":")[0]
        return tuple(dict.fromkeys(m for m in (*self.modules, source) if m))

    def make_fn(self) -> str | Callable[..., gym.Env]:
        """The ``env_id`` argument for SB3's ``make_vec_env`` of a Gymnasium env: the id itself, or (when
        :attr:`modules` is not empty, and for sbagents' own ids) a picklable callable that imports them first, so
        subprocess workers find the env. (A game's seat env is :func:`sbagents.games.selfplay.make_selfplay_env`.)"""
        if self.modules:
            return functools.partial(make_registered, self.env_id, self.modules)
        if self.env_id.startswith("sbagents/"):
            # sbagents' own ids are registered by importing sbagents: the plain id finds them in a worker only
            # where the parent's ``__main__`` imports sbagents (``python -m sbagents.train``; not pytest, a notebook
            # or ``python -c``), so the worker imports the registration itself
            return functools.partial(make_registered, self.env_id, ("sbagents.registration",))
        return self.env_id

    def parallel_env_fn(self) -> Callable[..., Any]:
        """A picklable ``(**kwargs) -> ParallelEnv`` of a PettingZoo env (it imports :attr:`modules` first)."""
        return functools.partial(make_parallel_env, self.source, self.modules)

    def parallel_env(self, **kwargs: Any) -> Any:
        """Build one ``ParallelEnv`` of this PettingZoo env."""
        return make_parallel_env(self.source, self.modules, **kwargs)


def is_module_path(name: str) -> bool:
    """Whether ``name`` reads as an absolute module path (``pkg.module``: identifiers joined by dots; not ``.x``,
    ``../etc/passwd`` or an empty name, which ``importlib`` would reject with a TypeError or ValueError)."""
    parts = name.split(".")
    return all(part.isidentifier() and not keyword.iskeyword(part) for part in parts)


def _top_importable(top: str) -> bool:
    try:
        importlib.import_module(top)
    except ImportError:
        return False
    return True


def missing_extra(exc: ImportError, module_name: str) -> UsageError | None:
    """The one-line :class:`UsageError` naming the extra to install when importing ``module_name`` failed because
    an optional package of :data:`OPTIONAL_MODULES` is not installed (None for any other import error)."""
    for name in (exc.name or "", module_name):
        top = name.split(".")[0]
        if top in OPTIONAL_MODULES and not _top_importable(top):
            extra = OPTIONAL_MODULES[top]
            return UsageError(f"{module_name} needs the optional package {top!r}, which is not installed: "
                              f"pip install 'sbagents[{extra}]'")
    return None


def import_packages(packages: list[str] | tuple[str, ...]) -> None:
    """Import user packages that register envs on import (``--gym-packages``)."""
    for name in packages:
        if not is_module_path(name):
            raise UsageError(f"--gym-packages: {name!r:.80} is not a module name (like my_package or pkg.envs)")
        try:
            importlib.import_module(name)
        except ImportError as exc:
            raise missing_extra(exc, name) or UsageError(f"--gym-packages: cannot import {name!r}: {exc}") from None


def make_registered(env_id: str, modules: tuple[str, ...], **kwargs: Any) -> gym.Env:
    """Import ``modules`` (which register ``env_id``), then ``gym.make`` it as SB3's ``make_vec_env`` does
    for a string id (``render_mode="rgb_array"`` unless the env does not take it or kwargs say otherwise)."""
    import_packages(modules)
    try:
        return gym.make(env_id, **{"render_mode": "rgb_array", **kwargs})
    except TypeError:
        return gym.make(env_id, **kwargs)


def pettingzoo_factory(source: str) -> Callable[..., Any]:
    """The ``(**kwargs) -> ParallelEnv`` that ``source`` names (``module`` -> its ``parallel_env``)."""
    module_name, _, attr = source.partition(":")
    module = importlib.import_module(module_name)
    return getattr(module, attr or "parallel_env")  # type: ignore[no-any-return]


def make_parallel_env(source: str, modules: tuple[str, ...] = (), **kwargs: Any) -> Any:
    """Import ``modules``, then build the PettingZoo env ``source`` names with ``kwargs``.

    An env module of :data:`~sbagents.registration.ARRAY_IMPLEMENTATIONS` is built by its array implementation
    where the kwargs allow (``mpe2.simple_spread_v3`` with discrete actions and no rendering is
    :class:`sbagents.batched.spread_env.SimpleSpreadParallelEnv`: step for step the same env, several times faster);
    otherwise an env module of :data:`~sbagents.registration.METRIC_OBSERVERS` gets its metrics observer.
    """
    import_packages(modules)
    module, _, attr = source.partition(":")
    own = attr in ("", "parallel_env")
    array = ARRAY_IMPLEMENTATIONS.get(module) if own else None
    if array is not None:
        env = pettingzoo_factory(array)(**kwargs)
        if env is not None:
            return env
    env = pettingzoo_factory(source)(**kwargs)
    observer = METRIC_OBSERVERS.get(module) if own else None
    return pettingzoo_factory(observer)(env) if observer is not None else env


def _register_atari() -> None:
    try:
        import ale_py
    except ImportError:
        return
    gym.register_envs(ale_py)


def _import(module_name: str) -> ModuleType | None:
    """The module ``module_name``; None when there is no such module (or the name is not a module path); a one-line
    error when it exists but cannot be imported (naming the extra to install for a missing optional package)."""
    if not is_module_path(module_name):
        return None
    try:
        return importlib.import_module(module_name)
    except ImportError as exc:
        missing = missing_extra(exc, module_name)
        if missing is not None:
            raise missing from None
        if exc.name is not None and module_name.startswith(exc.name):
            return None  # no such module: not a module path
        raise UsageError(f"cannot import {module_name!r}: {exc}") from None


@functools.cache
def _returns_aec_env(fn: Callable[..., Any]) -> bool:
    """Whether ``fn()`` builds a turn-based (AEC) env rather than a ``ParallelEnv`` (one is built to see, once per
    function: the team and the game kind both ask)."""
    try:
        env = fn()
    except Exception:  # noqa: BLE001 - a function that needs arguments: treated as a ParallelEnv source
        return False
    is_aec = is_aec_env(env)
    env.close()
    return is_aec


def is_aec_env(env: Any) -> bool:
    """Whether ``env`` is a PettingZoo AEC env (it has ``agent_iter`` and ``observe``)."""
    return callable(getattr(env, "agent_iter", None)) and callable(getattr(env, "observe", None))


def callable_env_id(module_name: str, attr: str) -> str:
    """The name of the PettingZoo env ``module_name:attr``: the module's (as ``--env module``) for PettingZoo's own
    entry points ``parallel_env`` and ``env``, else ``module_name:attr`` (any other callable: a name of its own)."""
    if attr in ("parallel_env", "env"):
        return module_name.rpartition(".")[2]
    return f"{module_name}:{attr}"


def _module_and_name(name: str) -> tuple[str, str] | None:
    """``module:name`` split in two (None for a name without ``:``).

    :raises UsageError: a ``:`` name whose module part is not a module path, or with nothing after the ``:``.
    """
    if ":" not in name:
        return None
    module_name, _, attr = name.partition(":")
    if not is_module_path(module_name) or not attr:
        raise UsageError(f"--env {name!r:.120} is not an env id, a module path or module:name "
                         "(e.g. sbagents/GridWorld-v0, mpe2.simple_spread_v3, my_pkg.envs:MyEnv-v0)")
    return module_name, attr


def _named_module(module_name: str, name: str) -> ModuleType:
    module = _import(module_name)
    if module is None:
        raise UsageError(f"cannot import module {module_name!r} of --env {name}")
    return module


def claim_gymnasium_id(name: str, modules: tuple[str, ...]) -> EnvRef | None:
    """The single-agent kind's claim: a Gymnasium ID (with or without the ``sbagents/`` namespace; an Atari id
    registers ``ale_py``'s envs first), or ``module:EnvId`` registered by that module."""
    split = _module_and_name(name)
    if split is not None:
        module_name, attr = split
        _named_module(module_name, name)
        found = next((c for c in (attr, f"sbagents/{attr}") if c in gym.registry), None)
        return EnvRef(found, modules=(*modules, module_name)) if found is not None else None
    if "NoFrameskip" in name or name.startswith("ALE/"):
        _register_atari()
        modules += ("ale_py",)
    found = next((c for c in (name, f"sbagents/{name}") if c in gym.registry), None)
    return EnvRef(found, modules=modules) if found is not None else None


def claim_pettingzoo(name: str, modules: tuple[str, ...], kind: EnvKind) -> EnvRef | None:
    """A PettingZoo kind's claim (``kind`` is :data:`TEAM` or :data:`GAME`): a short name of
    :data:`~sbagents.registration.PETTINGZOO_ENVS` (a team), a module with ``parallel_env`` (a team) or only ``env``
    (a turn-based game), or ``module:callable`` building a ``ParallelEnv`` (a team) or an AEC env (a game)."""
    if kind is TEAM and name in PETTINGZOO_ENVS:
        return EnvRef(name, TEAM, modules=modules, source=PETTINGZOO_ENVS[name])
    split = _module_and_name(name)
    if split is not None:
        module_name, attr = split
        factory = getattr(_named_module(module_name, name), attr, None)
        if not callable(factory) or _returns_aec_env(factory) != (kind is GAME):
            return None
        return EnvRef(callable_env_id(module_name, attr), kind, modules=modules, source=name)
    module = _import(name) if "." in name else None
    if module is None:
        return None
    team_module = callable(getattr(module, "parallel_env", None))
    if team_module if kind is TEAM else not team_module and callable(getattr(module, "env", None)):
        return EnvRef(name.rpartition(".")[2], kind, modules=modules, source=name)
    return None


def resolve_env(name: str, gym_packages: list[str] | tuple[str, ...] = ()) -> EnvRef:
    """Resolve ``name`` to an env, or raise :class:`UsageError` suggesting close ids.

    Every kind is asked whether it claims the name (:meth:`~sbagents.core.env_kinds.EnvKind.claim`): first those
    added with :func:`~sbagents.core.env_kinds.register_env_kind` (latest first), then the built-in ones. Between
    them they accept a Gymnasium ID (``sbagents/GridWorld-v0``, ``Pendulum-v1``, ``PongNoFrameskip-v4``), the same
    without the ``sbagents/`` namespace, ``module:EnvId`` (the module is imported first, as ``gym.make`` does), a
    PettingZoo env module path, ``module:callable`` returning a ``ParallelEnv`` or an AEC game, and the short names of
    :data:`~sbagents.registration.PETTINGZOO_ENVS`.
    """
    import_packages(gym_packages)
    modules = tuple(gym_packages)
    for kind in (*REGISTERED_KINDS, *builtin_kinds()):
        claimed = kind.claim(name, modules)
        if claimed is not None:
            return claimed
    raise _unclaimed(name)


def _unclaimed(name: str) -> UsageError:
    """The one-line error for a name no kind claims: what it is not, or close ids."""
    split = _module_and_name(name)
    if split is not None:
        module_name, attr = split
        return UsageError(f"{attr!r} is neither a Gymnasium ID registered by {module_name} nor a function in it")
    if "." in name and _import(name) is not None:
        return UsageError(f"module {name} has no parallel_env(**kwargs); name a PettingZoo env module, or "
                          f"'{name}:<function>' for a function that returns a ParallelEnv")
    known = list(gym.registry) + list(PETTINGZOO_ENVS)
    close = difflib.get_close_matches(name, known, n=3, cutoff=0.5)
    hint = f"; did you mean {', '.join(close)}?" if close else "; see python -m sbagents.train --list"
    from sbagents.source_tree import shadowing_folder, shadowing_hint

    shadow = shadowing_folder()
    if shadow is not None:  # sbagents/__init__.py never ran: its ids are not registered
        hint = f"; {shadowing_hint(shadow)}"
    return UsageError(f"unknown env id {name!r}{hint}")


def sbagents_env_ids() -> list[str]:
    """Every env id sbagents ships (Gymnasium IDs, then PettingZoo names)."""
    return sorted(k for k in gym.registry if k.startswith("sbagents/")) + sorted(PETTINGZOO_ENVS)
