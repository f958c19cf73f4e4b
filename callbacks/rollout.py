"""Evaluating a model on a VecEnv with the episode runner (:mod:`sbagents.callbacks.episodes`): the front used by
the adversarial and fairness evaluations (works with team VecEnvs), and :class:`EpisodeEvalCallback`, which makes
SB3's periodic ``EvalCallback`` play its episodes with the runner."""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, sync_envs_normalization

from sbagents.atomic import save_model
from sbagents.callbacks.common import find_vec_normalize
from sbagents.callbacks.episodes import EpisodeRecord, Policy, model_actor, play_episodes, stateless, summarize_records
from sbagents.state_files import BEST_VECNORMALIZE_FILE, save_vecnormalize

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


class EpisodeEvalCallback:
    """Mixin for SB3's ``EvalCallback`` and sb3-contrib's ``MaskableEvalCallback`` (put it before them): the
    periodic evaluation plays its episodes with :func:`~sbagents.callbacks.episodes.play_episodes` under
    ``evaluate_policy``'s rules (``monitor_episodes=True``; legal-action masks when the callback has
    ``use_masking``), the rest (``evaluations.npz``, logged keys, best model, child callbacks) as SB3 does it, and
    the best model is kept with the ``VecNormalize`` statistics of its moment (``vecnormalize_best.npz``).
    With ``render=True`` the parent's own loop runs (it draws every step)."""

    eval_env: VecEnv
    model: BaseAlgorithm
    training_env: VecEnv
    n_calls: int
    num_timesteps: int
    eval_freq: int
    n_eval_episodes: int
    deterministic: bool
    render: bool
    verbose: int
    log_path: str | None
    best_model_save_path: str | None
    best_mean_reward: float
    last_mean_reward: float
    evaluations_timesteps: list[int]
    evaluations_results: list[list[float]]
    evaluations_length: list[list[int]]
    evaluations_successes: list[list[bool]]
    _is_success_buffer: list[bool]
    callback: Any
    callback_on_new_best: Any
    logger: Any

    def _episode_actor(self) -> Policy:
        if not getattr(self, "use_masking", False):
            return model_actor(self.model, self.deterministic)
        env = self.eval_env
        return model_actor(self.model, self.deterministic, lambda: np.stack(env.env_method("action_masks")))

    def _on_step(self) -> bool:
        if self.render or self.eval_freq <= 0 or self.n_calls % self.eval_freq != 0:
            return super()._on_step()  # type: ignore[misc,no-any-return]
        continue_training = True
        if self.model.get_vec_normalize_env() is not None:
            try:
                sync_envs_normalization(self.training_env, self.eval_env)
            except AttributeError as e:
                raise AssertionError("Training and eval env are not wrapped the same way") from e
        records = play_episodes(self.eval_env, self._episode_actor(), self.n_eval_episodes, monitor_episodes=True)
        episode_rewards, episode_lengths = [r.ret for r in records], [r.length for r in records]
        self._is_success_buffer = [r.info["is_success"] for r in records if r.info.get("is_success") is not None]
        if self.log_path is not None:
            self.evaluations_timesteps.append(self.num_timesteps)
            self.evaluations_results.append(episode_rewards)
            self.evaluations_length.append(episode_lengths)
            kwargs = {}
            if len(self._is_success_buffer) > 0:
                self.evaluations_successes.append(self._is_success_buffer)
                kwargs = {"successes": self.evaluations_successes}
            np.savez(self.log_path, timesteps=self.evaluations_timesteps, results=self.evaluations_results,
                     ep_lengths=self.evaluations_length, **kwargs)  # type: ignore[arg-type]
        mean_reward, std_reward = np.mean(episode_rewards), np.std(episode_rewards)
        mean_ep_length, std_ep_length = np.mean(episode_lengths), np.std(episode_lengths)
        self.last_mean_reward = float(mean_reward)
        if self.verbose >= 1:
            print(f"Eval num_timesteps={self.num_timesteps}, episode_reward={mean_reward:.2f} +/- {std_reward:.2f}")
            print(f"Episode length: {mean_ep_length:.2f} +/- {std_ep_length:.2f}")
        self.logger.record("eval/mean_reward", float(mean_reward))
        self.logger.record("eval/mean_ep_length", mean_ep_length)
        if len(self._is_success_buffer) > 0:
            success_rate = np.mean(self._is_success_buffer)
            if self.verbose >= 1:
                print(f"Success rate: {100 * success_rate:.2f}%")
            self.logger.record("eval/success_rate", success_rate)
        self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
        self.logger.dump(self.num_timesteps)
        if mean_reward > self.best_mean_reward:
            if self.verbose >= 1:
                print("New best mean reward!")
            if self.best_model_save_path is not None:  # the statistics of this moment first, then the model
                venv = self.model.get_vec_normalize_env()
                if venv is not None:
                    save_vecnormalize(venv, Path(self.best_model_save_path) / BEST_VECNORMALIZE_FILE)
                save_model(self.model, Path(self.best_model_save_path) / "best_model.zip")
            self.best_mean_reward = float(mean_reward)
            if self.callback_on_new_best is not None:
                continue_training = self.callback_on_new_best.on_step()
        if self.callback is not None:
            continue_training = continue_training and self._on_event()  # type: ignore[attr-defined]
        return continue_training
