"""Resolving the ``--env`` argument: Gymnasium IDs, PettingZoo modules, ``module:EnvId`` and user packages."""

from __future__ import annotations

import difflib
import functools
import importlib
from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import gymnasium as gym

from sbagents.errors import UsageError

#: Multi-agent envs the CLI accepts by name -> PettingZoo module (with ``parallel_env(**kwargs)``).
PETTINGZOO_ENVS: dict[str, str] = {"treasure_hunt_v0": "sbagents.envs.treasure_hunt_v0"}


@dataclass(frozen=True)
class EnvRef:
    """A resolved env name.

    :param env_id: canonical id (a Gymnasium ID, or the PettingZoo env name).
    :param multi_agent: True for PettingZoo parallel envs.
    :param modules: modules to import before ``gym.make(env_id)`` in any process (``--gym-packages``, the
        ``module`` of ``module:EnvId``, ``ale_py`` for Atari ids): a ``SubprocVecEnv`` worker starts with a
        registry that has none of their envs.
    """

    env_id: str
    multi_agent: bool = False
    modules: tuple[str, ...] = ()

    @property
    def is_atari(self) -> bool:
        """Whether this is an ALE id (RL Zoo's ``atari`` config entry applies)."""
        return "NoFrameskip" in self.env_id or self.env_id.startswith("ALE/")

    def make_fn(self) -> str | Callable[..., gym.Env]:
        """The ``env_id`` argument for SB3's ``make_vec_env``: the id itself, or (when :attr:`modules` is not
        empty) a picklable callable that imports them first, so subprocess workers find the env."""
        if not self.modules:
            return self.env_id
        return functools.partial(make_registered, self.env_id, self.modules)

    def pettingzoo_module(self) -> ModuleType:
        """The PettingZoo module of a multi-agent env."""
        return importlib.import_module(PETTINGZOO_ENVS[self.env_id])


def import_packages(packages: list[str] | tuple[str, ...]) -> None:
    """Import user packages that register envs on import (``--gym-packages``)."""
    for name in packages:
        try:
            importlib.import_module(name)
        except ImportError as exc:
            raise UsageError(f"--gym-packages: cannot import {name!r}: {exc}") from None


def make_registered(env_id: str, modules: tuple[str, ...], **kwargs: Any) -> gym.Env:
    """Import ``modules`` (which register ``env_id``), then ``gym.make`` it as SB3's ``make_vec_env`` does
    for a string id (``render_mode="rgb_array"`` unless the env does not take it or kwargs say otherwise)."""
    import_packages(modules)
    try:
        return gym.make(env_id, **{"render_mode": "rgb_array", **kwargs})
    except TypeError:
        return gym.make(env_id, **kwargs)


def _register_atari() -> None:
    try:
        import ale_py
    except ImportError:
        return
    gym.register_envs(ale_py)


def resolve_env(name: str, gym_packages: list[str] | tuple[str, ...] = ()) -> EnvRef:
    """Resolve ``name`` to a registered env, or raise :class:`UsageError` suggesting close ids.

    Accepts a Gymnasium ID (``sbagents/GridWorld-v0``, ``Pendulum-v1``, ``PongNoFrameskip-v4``), the same
    without the ``sbagents/`` namespace, ``module:EnvId`` (the module is imported first, as ``gym.make``
    does) and the PettingZoo names in :data:`PETTINGZOO_ENVS`.
    """
    import_packages(gym_packages)
    if name in PETTINGZOO_ENVS:
        return EnvRef(name, multi_agent=True)
    modules = tuple(gym_packages)
    if ":" in name:
        module, _, name = name.partition(":")
        import_packages([module])
        modules += (module,)
    atari = "NoFrameskip" in name or name.startswith("ALE/")
    if atari:
        _register_atari()
        modules += ("ale_py",)
    for candidate in (name, f"sbagents/{name}"):
        if candidate in gym.registry:
            return EnvRef(candidate, modules=modules)
    known = list(gym.registry) + list(PETTINGZOO_ENVS)
    close = difflib.get_close_matches(name, known, n=3, cutoff=0.5)
    hint = f"; did you mean {', '.join(close)}?" if close else "; see python -m sbagents.train --list"
    raise UsageError(f"unknown env id {name!r}{hint}")


def sbagents_env_ids() -> list[str]:
    """Every env id sbagents ships (Gymnasium IDs, then PettingZoo names)."""
    return sorted(k for k in gym.registry if k.startswith("sbagents/")) + sorted(PETTINGZOO_ENVS)
