"""A human-readable look at a trained policy, printed at the end of ``train`` (the book's ASCII path)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm

from sbagents.callbacks.episodes import model_actor
from sbagents.core.experiment import Experiment


def greedy_path(model: BaseAlgorithm, env: gym.Env, max_steps: int = 1000) -> tuple[list[tuple[int, int]], float]:
    """Follow the deterministic policy for one episode on a grid env (one exposing ``agent``).

    :return: the visited cells (start included) and the episode return.
    """
    policy = model_actor(model, deterministic=True)
    obs, _ = env.reset(seed=0)
    base = env.unwrapped
    path, total = [base.agent], 0.0  # type: ignore[attr-defined]
    state, start = None, np.ones(1, dtype=bool)
    for _ in range(max_steps):
        action, state = policy(obs, state, start)
        start = np.zeros(1, dtype=bool)
        obs, reward, terminated, truncated, _ = env.step(action)
        path.append(base.agent)  # type: ignore[attr-defined]
        total += float(reward)
        if terminated or truncated:
            break
    return path, total


def describe_policy(model: BaseAlgorithm, exp: Experiment) -> str | None:
    """The learned path on the book's grid (``*`` marks it) and its return, for grid envs; else None."""
    if exp.normalize or exp.frame_stack or exp.env_wrapper or exp.env_id not in gym.registry:
        return None
    env = gym.make(exp.env_id, **exp.env_kwargs)
    base = env.unwrapped
    if not hasattr(base, "grid_text") or not hasattr(base, "agent"):
        env.close()
        return None
    path, total = greedy_path(model, env)
    env.reset(seed=0)
    text = base.grid_text(path)
    env.close()
    return f"learned path ({len(path) - 1} moves):\n{text}\nreturn: {total:g}"
