"""Episode runner shared by the adversarial and fairness evaluations (works with multi-agent VecEnvs)."""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv

from sbagents.callbacks.common import agent_layout, find_vec_normalize
from sbagents.callbacks.safety import step_violation


@dataclass
class EpisodeResult:
    """One evaluation episode. With a multi-agent VecEnv the return is the team return (sum over agents)."""

    ret: float
    length: int
    success: bool | None
    violations: int
    cost: float
    info: dict[str, Any] = field(default_factory=dict)
    agent_returns: dict[str, float] = field(default_factory=dict)


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
) -> list[EpisodeResult]:
    """Run ``n_episodes`` episodes of ``model`` on ``env`` and return them in completion order.

    This is the one episode runner of sbagents: evaluation of single-agent and team (parameter-sharing) VecEnvs,
    attacks, fairness, and the RLlib backend's policies (``model=None`` with an ``act`` function).

    Episodes are spread over the envs as in SB3's ``evaluate_policy`` (env ``i`` runs
    ``(n_episodes + i) // n_envs`` of them) so short episodes do not dominate. Rewards are unnormalized
    (``VecNormalize.get_original_reward``); a ``VecNormalize`` is frozen (``training=False``) meanwhile.

    :param act: maps a VecEnv observation batch to env actions (default ``model.predict``).
    :param seed: ``env.seed(seed)`` before the reset (same episodes for every call).
    :return: per episode: return, length, ``is_success`` of the last step (None when absent), violation
        steps and cost (:func:`step_violation`), the ``info`` of its last step (first agent's) and, for team
        VecEnvs, each agent's return.
    """
    if n_episodes < 1:
        raise ValueError(f"n_episodes must be >= 1, got {n_episodes}")
    n_agents, agents = agent_layout(env)
    n_groups = env.num_envs // n_agents
    targets = [(n_episodes + i) // n_groups for i in range(n_groups)]
    counts = [0] * n_groups
    ret, length = np.zeros(n_groups), np.zeros(n_groups, dtype=np.int64)
    slot_ret = np.zeros(env.num_envs)
    viol, cost = np.zeros(n_groups, dtype=np.int64), np.zeros(n_groups)
    vn = find_vec_normalize(env)
    was_training = vn.training if vn is not None else False
    if vn is not None:
        vn.training = False
    if act is None:
        if model is None:
            raise ValueError("run_episodes needs a model or an act function")
        policy_model = model

        def act(o: Any) -> np.ndarray:
            return policy_model.predict(o, deterministic=deterministic)[0]

    policy = getattr(model, "policy", None)  # any object with predict() will do; SB3 policies go to eval mode
    if policy is not None:
        policy.set_training_mode(False)
    episodes: list[EpisodeResult] = []
    try:
        if seed is not None:
            env.seed(seed)
        obs = env.reset()
        while sum(counts) < sum(targets):
            obs, rewards, dones, infos = env.step(act(obs))
            raw = vn.get_original_reward() if vn is not None else rewards
            for k, info in enumerate(infos):
                g = k // n_agents
                ret[g] += float(raw[k])
                slot_ret[k] += float(raw[k])
                kind, c = step_violation(info)
                viol[g] += kind is not None
                cost[g] += c
                if k % n_agents == n_agents - 1:
                    length[g] += 1
                    head = infos[k - n_agents + 1]
                    # a team VecEnv marks the end of the team's episode on its first slot; agents may end earlier
                    if ("episode" in head) if agents else dones[k]:
                        if counts[g] < targets[g]:
                            success = head.get("is_success")
                            by_agent = dict(zip(agents, slot_ret[k - n_agents + 1 : k + 1].tolist(), strict=True)
                                            ) if agents else {}
                            episodes.append(
                                EpisodeResult(
                                    float(ret[g]), int(length[g]), None if success is None else bool(success),
                                    int(viol[g]), float(cost[g]), dict(head), by_agent,
                                )
                            )
                            counts[g] += 1
                        ret[g], length[g], viol[g], cost[g] = 0.0, 0, 0, 0.0
                        slot_ret[k - n_agents + 1 : k + 1] = 0.0
    finally:
        if vn is not None:
            vn.training = was_training
    return episodes


def summarize_episodes(episodes: Sequence[EpisodeResult]) -> dict[str, Any]:
    """``episodes``, ``mean_return``, ``std_return``, ``mean_length``, ``success_rate`` (NaN when the env
    reports no ``is_success``), ``violations`` (total violation steps) and ``mean_ep_cost``."""
    returns = np.array([e.ret for e in episodes])
    succ = [e.success for e in episodes if e.success is not None]
    return {
        "episodes": len(episodes),
        "mean_return": float(returns.mean()),
        "std_return": float(returns.std()),
        "mean_length": float(np.mean([e.length for e in episodes])),
        "success_rate": float(np.mean(succ)) if succ else float("nan"),
        "violations": int(sum(e.violations for e in episodes)),
        "mean_ep_cost": float(np.mean([e.cost for e in episodes])),
    }
