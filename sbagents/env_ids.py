"""Resolving the ``--env`` argument: Gymnasium IDs, PettingZoo modules, ``module:EnvId`` and user packages."""

from __future__ import annotations

import difflib
import importlib
from dataclasses import dataclass
from types import ModuleType

import gymnasium as gym

from sbagents.errors import UsageError

#: Multi-agent envs the CLI accepts by name -> PettingZoo module (with ``parallel_env(**kwargs)``).
PETTINGZOO_ENVS: dict[str, str] = {"treasure_hunt_v0": "sbagents.envs.treasure_hunt_v0"}


@dataclass(frozen=True)
class EnvRef:
    """A resolved env name.

    :param env_id: canonical id (a Gymnasium ID, or the PettingZoo env name).
    :param multi_agent: True for PettingZoo parallel envs.
    """

    env_id: str
    multi_agent: bool = False

    @property
    def is_atari(self) -> bool:
        """Whether this is an ALE id (RL Zoo's ``atari`` config entry applies)."""
        return "NoFrameskip" in self.env_id or self.env_id.startswith("ALE/")

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


def _register_atari() -> None:
    try:
        import ale_py
    except ImportError:
        return
    gym.register_envs(ale_py)


def resolve_env(name: str, gym_packages: list[str] | tuple[str, ...] = ()) -> EnvRef:
    """Resolve ``name`` to a registered env, or raise :class:`UsageError` suggesting close ids.

    Accepts a Gymnasium ID (``sbagents/GridWorld-v0``, ``Pendulum-v1``, ``PongNoFrameskip-v4``), the same without
    the ``sbagents/`` namespace, ``module:EnvId`` (the module is imported first, as ``gym.make`` does) and
    the PettingZoo names in :data:`PETTINGZOO_ENVS`.
    """
    import_packages(gym_packages)
    if name in PETTINGZOO_ENVS:
        return EnvRef(name, multi_agent=True)
    if ":" in name:
        module, _, name = name.partition(":")
        import_packages([module])
    for candidate in (name, f"sbagents/{name}"):
        if candidate in gym.registry:
            return EnvRef(candidate)
    if "NoFrameskip" in name or name.startswith("ALE/"):
        _register_atari()
        if name in gym.registry:
            return EnvRef(name)
    known = list(gym.registry) + list(PETTINGZOO_ENVS)
    close = difflib.get_close_matches(name, known, n=3, cutoff=0.5)
    hint = f"; did you mean {', '.join(close)}?" if close else "; see python -m sbagents.train --list"
    raise UsageError(f"unknown env id {name!r}{hint}")


def sbagents_env_ids() -> list[str]:
    """Every env id sbagents ships (Gymnasium IDs, then PettingZoo names)."""
    return sorted(k for k in gym.registry if k.startswith("sbagents/")) + sorted(PETTINGZOO_ENVS)
