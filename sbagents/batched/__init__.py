"""Batched numpy VecEnvs for the grid worlds: every env copy stepped with array operations.

:func:`make_batched_vec_env` is the factory used by the env factory (``--vec-env batched``).
"""

from __future__ import annotations

import os
from typing import Any

from stable_baselines3.common.vec_env import VecEnv

from sbagents.batched.base import BatchedVecEnv
from sbagents.batched.gridworld import GRIDWORLD_ID, BatchedGridWorldVecEnv
from sbagents.batched.treasure_hunt import TREASURE_HUNT_ID, BatchedTreasureHuntVecEnv

#: Env ids that have a batched implementation.
BATCHED_ENV_IDS: tuple[str, ...] = (GRIDWORLD_ID, TREASURE_HUNT_ID)

__all__ = [
    "BATCHED_ENV_IDS",
    "BatchedGridWorldVecEnv",
    "BatchedTreasureHuntVecEnv",
    "BatchedVecEnv",
    "make_batched_vec_env",
]


def make_batched_vec_env(
    env_id: str, n_envs: int, seed: int | None, env_kwargs: dict[str, Any], monitor_dir: str | None
) -> VecEnv:
    """Batched VecEnv equivalent to the reference path of ``env_id``.

    - ``"sbagents/GridWorld-v0"``: like ``make_vec_env(env_id, n_envs, seed, monitor_dir=...)``
      (``n_envs`` slots, monitor files ``<monitor_dir>/<i>.monitor.csv``).
    - ``"treasure_hunt_v0"``: like :func:`sbagents.multiagent.parameter_sharing.make_parameter_sharing_vec_env`
      (``n_envs * n_agents`` slots, team episodes in ``<monitor_dir>/0.monitor.csv``).

    :param seed: env ``i`` is reset with ``seed + i`` at the first reset (``None``: random).
    :param env_kwargs: constructor kwargs of the env (``render_mode`` included).
    :raises ValueError: for any other env id.
    """
    kwargs = dict(env_kwargs or {})
    vec: BatchedGridWorldVecEnv | BatchedTreasureHuntVecEnv
    if env_id == GRIDWORLD_ID:
        vec = BatchedGridWorldVecEnv(n_envs, kwargs, monitor_dir, env_id)
        if seed is not None:
            vec.action_space.seed(seed)
        vec.seed(seed)  # as make_vec_env: always (random seeds when None)
        return vec
    if env_id == TREASURE_HUNT_ID:
        path = None if monitor_dir is None else os.path.join(monitor_dir, "0")
        vec = BatchedTreasureHuntVecEnv(n_envs, kwargs, path)
        if seed is not None:
            vec.seed(seed)
        return vec
    raise ValueError(f"no batched VecEnv for {env_id!r}; available: {', '.join(BATCHED_ENV_IDS)}")
