"""Evaluating a model on a VecEnv with the episode runner (:mod:`sbagents.callbacks.episodes`): the front used by
the adversarial and fairness evaluations (works with team VecEnvs)."""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv

from sbagents.callbacks.common import find_vec_normalize
from sbagents.callbacks.episodes import EpisodeRecord, Policy, model_actor, play_episodes, stateless, summarize_records

#: The former name of :class:`~sbagents.callbacks.episodes.EpisodeRecord`.
EpisodeResult = EpisodeRecord


def as_vec_env(env: gym.Env | VecEnv) -> VecEnv:
    """``env`` itself if it is a VecEnv, else a one-env ``DummyVecEnv`` around it."""
    return env if isinstance(env, VecEnv) else DummyVecEnv([lambda: env])


def sync_normalization(train_env: VecEnv | None, eval_env: VecEnv) -> None:
    """Copy ``VecNormalize`` statistics from ``train_env`` to ``eval_env`` when both have one."""
    if train_env is None:
        return
    src, dst = find_vec_normalize(train_env), find_vec_normalize(eval_env)
    if src is not None and dst is not None:
        dst.obs_rms = copy.deepcopy(src.obs_rms)
        dst.ret_rms = copy.deepcopy(src.ret_rms)


def run_episodes(
    model: BaseAlgorithm | Any | None,
    env: VecEnv,
    n_episodes: int,
    deterministic: bool = True,
    seed: int | None = None,
    act: Callable[[Any], np.ndarray] | None = None,
    policy: Policy | None = None,
) -> list[EpisodeRecord]:
    """Run ``n_episodes`` episodes of ``model`` on ``env`` with :func:`~sbagents.callbacks.episodes.play_episodes`
    and return their records in completion order.

    :param model: anything with SB3's ``predict`` (an SB3 policy is put in eval mode), or None with ``act`` or
        ``policy``.
    :param act: a stateless ``obs batch -> env actions`` to act with instead of ``model.predict``.
    :param policy: a :class:`~sbagents.callbacks.episodes.Policy` to act with (state carried, e.g. an attacked
        recurrent policy); default: ``model``'s, through ``predict(obs, state, episode_start)``.
    :param seed: ``env.seed(seed)`` before the reset (same episodes for every call).
    """
    if n_episodes < 1:
        raise ValueError(f"n_episodes must be >= 1, got {n_episodes}")
    if policy is None and act is not None:
        policy = stateless(act)
    if policy is None:
        if model is None:
            raise ValueError("run_episodes needs a model, an act function or a policy")
        policy = model_actor(model, deterministic)
    else:
        sb3_policy = getattr(model, "policy", None)
        if sb3_policy is not None:
            sb3_policy.set_training_mode(False)
    return play_episodes(env, policy, n_episodes, seed)


def summarize_episodes(episodes: Sequence[EpisodeRecord]) -> dict[str, Any]:
    """The columns of an attack row: ``episodes``, ``mean_return``, ``std_return``, ``mean_length``,
    ``success_rate`` (NaN when the env reports no ``is_success``), ``violations`` (total violation steps) and
    ``mean_ep_cost`` (mean episode cost, 0 for an episode that reports none); the first four as in
    :func:`~sbagents.callbacks.episodes.summarize_records`."""
    summary = summarize_records(episodes)
    success = summary["success_rate"]
    return {
        "episodes": summary["n_episodes"],
        "mean_return": summary["mean_return"],
        "std_return": summary["std_return"],
        "mean_length": summary["mean_length"],
        "success_rate": float("nan") if success is None else success,
        "violations": int(sum(e.violations for e in episodes)),
        "mean_ep_cost": float(np.mean([e.cost or 0.0 for e in episodes])),
    }
