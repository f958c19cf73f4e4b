"""Batched numpy VecEnvs for the grid worlds, MPE simple spread and SISL pursuit: every env copy stepped with array
operations.

:func:`make_batched_vec_env` is the factory used by the env factory (``--vec-env batched``);
:func:`batched_env_id` and :func:`unbatchable_kwargs` tell whether an env (and its kwargs) has one.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from typing import Any

from stable_baselines3.common.vec_env import VecEnv

from sbagents.batched.base import BatchedVecEnv
from sbagents.batched.gridworld import GRIDWORLD_ID, BatchedGridWorldVecEnv
from sbagents.batched.pursuit import PURSUIT_ID, PURSUIT_SOURCES, PURSUIT_SUPPORT, BatchedPursuitVecEnv
from sbagents.batched.pursuit import unsupported_kwargs as unsupported_pursuit_kwargs
from sbagents.batched.simple_spread import (
    SIMPLE_SPREAD_ID,
    SIMPLE_SPREAD_SOURCES,
    SIMPLE_SPREAD_SUPPORT,
    BatchedSimpleSpreadVecEnv,
)
from sbagents.batched.simple_spread import unsupported_kwargs as unsupported_spread_kwargs
from sbagents.batched.treasure_hunt import TREASURE_HUNT_ID, BatchedTreasureHuntVecEnv

#: Env ids that have a batched implementation (``mpe2.simple_spread_v3``: the ``--env`` name, the env's source).
BATCHED_ENV_IDS: tuple[str, ...] = (GRIDWORLD_ID, TREASURE_HUNT_ID, SIMPLE_SPREAD_ID, PURSUIT_ID)
#: What the batched implementations support, for error messages.
BATCHED_SUPPORT = (f"{GRIDWORLD_ID}, {TREASURE_HUNT_ID}, {SIMPLE_SPREAD_ID} ({SIMPLE_SPREAD_SUPPORT}), "
                   f"{PURSUIT_ID} ({PURSUIT_SUPPORT})")

__all__ = [
    "BATCHED_ENV_IDS",
    "BATCHED_SUPPORT",
    "BatchedGridWorldVecEnv",
    "BatchedPursuitVecEnv",
    "BatchedSimpleSpreadVecEnv",
    "BatchedTreasureHuntVecEnv",
    "BatchedVecEnv",
    "batched_env_id",
    "make_batched_vec_env",
    "unbatchable_kwargs",
]


def batched_env_id(env_id: str, source: str = "") -> str | None:
    """The id of the batched implementation of an env, or None.

    :param env_id: the env's id (``EnvRef.env_id``: a Gymnasium id or a PettingZoo env's name).
    :param source: a PettingZoo env's source (``EnvRef.source``, ``pkg.module[:callable]``); ``""`` otherwise.
    """
    if env_id in (GRIDWORLD_ID, TREASURE_HUNT_ID):
        return env_id
    if source in SIMPLE_SPREAD_SOURCES:
        return SIMPLE_SPREAD_ID
    if source in PURSUIT_SOURCES:
        return PURSUIT_ID
    return None


def unbatchable_kwargs(batched_id: str, env_kwargs: Mapping[str, Any]) -> list[str]:
    """The env kwargs (``key=value``) the batched implementation ``batched_id`` does not reproduce (empty: none)."""
    if batched_id == SIMPLE_SPREAD_ID:
        return unsupported_spread_kwargs(env_kwargs)
    if batched_id == PURSUIT_ID:
        return unsupported_pursuit_kwargs(env_kwargs)
    return []


def make_batched_vec_env(
    env_id: str, n_envs: int, seed: int | None, env_kwargs: dict[str, Any], monitor_dir: str | None
) -> VecEnv:
    """Batched VecEnv equivalent to the reference path of ``env_id``.

    - ``"sbagents/GridWorld-v0"``: like ``make_vec_env(env_id, n_envs, seed, monitor_dir=...)``
      (``n_envs`` slots, monitor files ``<monitor_dir>/<i>.monitor.csv``).
    - ``"treasure_hunt_v0"``: like :func:`sbagents.multiagent.parameter_sharing.make_parameter_sharing_vec_env`
      (``n_envs * n_agents`` slots, team episodes in ``<monitor_dir>/0.monitor.csv``).
    - ``"mpe2.simple_spread_v3"`` (discrete actions; see :func:`unbatchable_kwargs`): like the ``policies: shared``
      team VecEnv of ``mpe2.simple_spread_v3.parallel_env`` (``n_envs * N`` slots, team episodes in
      ``<monitor_dir>/0.monitor.csv``).
    - ``"pettingzoo.sisl.pursuit_v5"`` (see :func:`unbatchable_kwargs`): likewise, for
      ``pettingzoo.sisl.pursuit_v5.parallel_env``.

    :param seed: env ``i`` is reset with ``seed + i`` at the first reset (``None``: random).
    :param env_kwargs: constructor kwargs of the env (``render_mode`` included).
    :raises ValueError: for any other env id, or kwargs the batched env does not reproduce.
    """
    kwargs = dict(env_kwargs or {})
    vec: BatchedVecEnv
    if env_id == GRIDWORLD_ID:
        vec = BatchedGridWorldVecEnv(n_envs, kwargs, monitor_dir, env_id)
        if seed is not None:
            vec.action_space.seed(seed)
        vec.seed(seed)  # as make_vec_env: always (random seeds when None)
        return vec
    team_envs: dict[str, Callable[..., BatchedVecEnv]] = {
        TREASURE_HUNT_ID: BatchedTreasureHuntVecEnv, SIMPLE_SPREAD_ID: BatchedSimpleSpreadVecEnv,
        PURSUIT_ID: BatchedPursuitVecEnv}
    if env_id in team_envs:
        path = None if monitor_dir is None else os.path.join(monitor_dir, "0")
        vec = team_envs[env_id](n_envs, kwargs, path)
        if seed is not None:
            vec.seed(seed)
        return vec
    raise ValueError(f"no batched VecEnv for {env_id!r}; available: {', '.join(BATCHED_ENV_IDS)}")
