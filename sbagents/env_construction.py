"""One env of an :class:`~sbagents.core.env_names.EnvRef`, whatever its kind: the class or function that builds it,
the keyword arguments it takes (checked before anything is built), its render modes, and the one-line errors of a
missing optional dependency or of kwargs the env rejects. :mod:`sbagents.env_factory` builds the VecEnvs from it.
"""

from __future__ import annotations

import functools
import importlib
import inspect
from collections.abc import Callable
from typing import Any

import gymnasium as gym

from sbagents.core.env_kinds import EnvKind, GameKind, TeamKind, kind_operation
from sbagents.core.env_names import EnvRef, pettingzoo_factory
from sbagents.core.experiment import Experiment
from sbagents.errors import UsageError


def env_constructor(ref: EnvRef) -> Callable[..., Any]:
    """The class or function that builds one env of ``ref`` (for keyword checks)."""
    return _constructor(ref.kind, ref)


@kind_operation()
def _constructor(kind: EnvKind, ref: EnvRef) -> Callable[..., Any]:
    """A Gymnasium env: its registered entry point."""
    entry_point = gym.spec(ref.env_id).entry_point
    if callable(entry_point):
        return entry_point
    try:
        return gym.envs.registration.load_env_creator(str(entry_point))
    except gym.error.DependencyNotInstalled as exc:
        raise missing_dependency_error(ref, exc) from None


@_constructor.register
def _team_constructor(kind: TeamKind, ref: EnvRef) -> Callable[..., Any]:
    return pettingzoo_factory(ref.source)


@_constructor.register
def _game_constructor(kind: GameKind, ref: EnvRef) -> Callable[..., Any]:
    from sbagents.games.aec import game_factory

    return game_factory(ref.source)


@kind_operation(TeamKind)
def env_fn(kind: EnvKind, ref: EnvRef) -> str | Callable[..., gym.Env]:
    """The ``env_id`` argument of SB3's ``make_vec_env`` for a Gymnasium env (picklable)."""
    return ref.make_fn()


@env_fn.register
def _game_env_fn(kind: GameKind, ref: EnvRef) -> str | Callable[..., gym.Env]:
    """A game's seat env (picklable)."""
    from sbagents.games.selfplay import make_selfplay_env

    return functools.partial(make_selfplay_env, ref.source, ref.modules)


class MissingDependencyError(UsageError):
    """An env whose optional dependency is not installed (one line naming the package or extra to install)."""


def missing_dependency_error(ref: EnvRef, exc: Exception) -> MissingDependencyError:
    """The :class:`MissingDependencyError` of Gymnasium's ``DependencyNotInstalled`` (whose message names the
    package or extra to install) for the env ``ref``."""
    reason = " ".join(str(exc).split()) or type(exc).__name__
    return MissingDependencyError(f"{ref.env_id} needs an optional dependency that is not installed: {reason}")


def _accepted_kwargs(ref: EnvRef) -> set[str] | None:
    """The keyword arguments ``ref``'s constructor takes, when they can be known (None: any)."""
    candidates: list[Any] = [env_constructor(ref)]
    if ref.kind.pettingzoo and ":" not in ref.source:  # PettingZoo's (parallel_)env forwards to raw_env
        module = importlib.import_module(ref.source)
        declared = getattr(module, "ACCEPTED_KWARGS", None)
        if declared is not None:
            return set(declared)
        candidates.append(getattr(module, "raw_env", None))
    for fn in candidates:
        try:
            params = inspect.signature(fn).parameters if fn is not None else None
        except (TypeError, ValueError):
            continue
        if params is not None and not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
            return set(params)
    return None


@kind_operation(TeamKind)
def _env_kwargs_of_env(kind: EnvKind, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """The env kwargs the env's constructor takes (a game's seat env takes self-play settings of its own)."""
    return env_kwargs


@_env_kwargs_of_env.register
def _game_env_kwargs_of_env(kind: GameKind, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    from sbagents.games.selfplay import SELFPLAY_KWARGS

    return {k: v for k, v in env_kwargs.items() if k not in SELFPLAY_KWARGS}


def check_env_kwargs(ref: EnvRef, env_kwargs: dict[str, Any]) -> None:
    """Raise :class:`UsageError` listing the accepted keys if ``env_kwargs`` has a key the env does not take."""
    env_kwargs = _env_kwargs_of_env(ref.kind, env_kwargs)
    if not env_kwargs:
        return
    names = _accepted_kwargs(ref)
    if names is None:
        return
    accepted = sorted(names - {"self", "render_mode"})
    unknown = sorted(set(env_kwargs) - names)
    if unknown:
        raise UsageError(
            f"unknown env kwarg(s) {', '.join(unknown)} for {ref.env_id}; accepted: {', '.join(accepted)}"
        )


def env_kwargs_error(ref: EnvRef, kwargs: dict[str, Any], exc: Exception) -> Exception:
    """The :class:`UsageError` of an env that cannot be built with the user's kwargs (else ``exc`` itself)."""
    user_kwargs = {k: v for k, v in kwargs.items() if k != "render_mode"}
    if not user_kwargs:
        return exc  # no user input involved: a bug, keep the traceback
    given = ", ".join(f"{k}={v!r}" for k, v in user_kwargs.items())
    reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return UsageError(f"cannot create {ref.env_id} with env kwargs {given}: {reason}")


def render_modes(exp: Experiment, ref: EnvRef) -> list[str]:
    """The render modes an env of ``exp`` declares (``metadata["render_modes"]``)."""
    return _render_modes(ref.kind, exp, ref)


@kind_operation(GameKind)
def _render_modes(kind: EnvKind, exp: Experiment, ref: EnvRef) -> list[str]:
    return list((getattr(env_constructor(ref), "metadata", None) or {}).get("render_modes", []))


@_render_modes.register
def _team_render_modes(kind: TeamKind, exp: Experiment, ref: EnvRef) -> list[str]:
    env = ref.parallel_env(**exp.env_kwargs)
    modes = list(env.metadata.get("render_modes", []))
    env.close()
    return modes
