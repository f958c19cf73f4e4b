"""Team evaluation of a parameter-shared policy: :func:`evaluate_team` and :class:`TeamEvalCallback`.

Team return = the sum of all agents' rewards over an episode; one result per team episode. The episodes are
played by :func:`sbagents.callbacks.rollout.run_episodes`, the runner every evaluation in sbagents uses.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from pettingzoo import ParallelEnv
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.vec_env import VecEnv, sync_envs_normalization

from sbagents.callbacks.rollout import EpisodeResult, run_episodes
from sbagents.multiagent.parameter_sharing import ParameterSharingVecEnv


def team_summary(episodes: Sequence[EpisodeResult]) -> dict[str, Any]:
    """``n_episodes``, ``mean_return``/``std_return`` (team return = sum over agents), ``mean_length``,
    ``success_rate`` (share of episodes whose last step reports ``is_success``) and ``metrics`` =
    ``{"treasures_per_episode", "team_return"}`` (NaN treasures if the env reports none)."""
    returns = [e.ret for e in episodes]
    treasures = [float(e.info.get("treasures_collected", np.nan)) for e in episodes]
    return {
        "n_episodes": len(episodes),
        "mean_return": float(np.mean(returns)),
        "std_return": float(np.std(returns)),
        "mean_length": float(np.mean([e.length for e in episodes])),
        "success_rate": float(np.mean([bool(e.success) for e in episodes])),
        "metrics": {"treasures_per_episode": float(np.mean(treasures)), "team_return": float(np.mean(returns))},
    }


def evaluate_team(
    model: Any,
    env: VecEnv | Callable[[], ParallelEnv],
    n_episodes: int = 10,
    deterministic: bool = True,
    seed: int | None = None,
    act: Callable[[Any], np.ndarray] | None = None,
) -> dict[str, Any]:
    """Play ``n_episodes`` team episodes (one team, sequentially) and summarize them.

    :param model: an SB3 model (``predict``), or None with ``act``.
    :param env: one ``ParameterSharingVecEnv`` team (under a frozen ``VecNormalize`` when the run normalized), or
        a zero-argument ``ParallelEnv`` constructor (a team VecEnv is built and closed here).
    :param seed: seed of the first reset (then the env's RNG continues) -> reproducible returns.
    :param act: maps an observation batch ``(n_agents, *obs_shape)`` to actions (default ``model.predict``).
    :return: :func:`team_summary` of the episodes.
    """
    if isinstance(env, VecEnv):
        return team_summary(run_episodes(model, env, n_episodes, deterministic, seed, act))
    venv = ParameterSharingVecEnv([env])
    try:
        return team_summary(run_episodes(model, venv, n_episodes, deterministic, seed, act))
    finally:
        venv.close()


class TeamEvalCallback(EvalCallback):
    """``EvalCallback`` that scores the team with :func:`evaluate_team` every ``eval_freq`` calls.

    Keeps ``best_model.zip`` (highest mean team return) in ``best_model_save_path`` and writes
    ``evaluations.npz`` in EvalCallback's format (``timesteps``, ``results`` team returns of shape
    ``(n_evals, n_eval_episodes)``, ``ep_lengths``, ``successes``) to ``log_path``. Logs ``eval/mean_reward``,
    ``eval/mean_ep_length``, ``eval/success_rate`` and ``eval/treasures_per_episode``.

    :param eval_env: a one-team parameter-sharing VecEnv (its ``VecNormalize`` statistics are synced from the
        training env before every evaluation).
    :param eval_freq: evaluate every ``eval_freq`` calls of ``_on_step`` (i.e. vec steps, not env steps).
    :param seed: seed of each evaluation (the same episodes every time; ``None``: fresh ones).
    """

    def __init__(
        self,
        eval_env: VecEnv,
        n_eval_episodes: int = 5,
        eval_freq: int = 10000,
        log_path: str | None = None,
        best_model_save_path: str | None = None,
        deterministic: bool = True,
        seed: int | None = None,
        callback_on_new_best: Any = None,
        callback_after_eval: Any = None,
        verbose: int = 1,
    ) -> None:
        super().__init__(
            eval_env,
            callback_on_new_best=callback_on_new_best,
            callback_after_eval=callback_after_eval,
            n_eval_episodes=n_eval_episodes,
            eval_freq=eval_freq,
            log_path=log_path,
            best_model_save_path=best_model_save_path,
            deterministic=deterministic,
            verbose=verbose,
            warn=False,
        )
        self.eval_seed = seed
        self.last_result: dict[str, Any] = {}

    def _init_callback(self) -> None:
        with warnings.catch_warnings():  # the eval env is the reference VecEnv; the training one may be batched
            warnings.filterwarnings("ignore", message="Training and eval env are not of the same type")
            super()._init_callback()

    def _on_step(self) -> bool:
        if self.eval_freq <= 0 or self.n_calls % self.eval_freq != 0:
            return True
        sync_envs_normalization(self.training_env, self.eval_env)
        episodes = run_episodes(self.model, self.eval_env, self.n_eval_episodes, self.deterministic, self.eval_seed)
        self.last_result = team_summary(episodes)
        self.evaluations_timesteps.append(self.num_timesteps)
        self.evaluations_results.append([e.ret for e in episodes])
        self.evaluations_length.append([e.length for e in episodes])
        self._is_success_buffer = [bool(e.success) for e in episodes]
        self.evaluations_successes.append(self._is_success_buffer)
        if self.log_path is not None:
            np.savez(
                self.log_path,
                timesteps=self.evaluations_timesteps,
                results=self.evaluations_results,
                ep_lengths=self.evaluations_length,
                successes=self.evaluations_successes,
            )
        mean_reward = float(self.last_result["mean_return"])
        self.last_mean_reward = mean_reward
        self.logger.record("eval/mean_reward", mean_reward)
        self.logger.record("eval/mean_ep_length", float(self.last_result["mean_length"]))
        self.logger.record("eval/success_rate", float(self.last_result["success_rate"]))
        self.logger.record("eval/treasures_per_episode", self.last_result["metrics"]["treasures_per_episode"])
        self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
        self.logger.dump(self.num_timesteps)
        continue_training = True
        if mean_reward > self.best_mean_reward:
            self.best_mean_reward = mean_reward
            if self.best_model_save_path is not None:
                self.model.save(os.path.join(self.best_model_save_path, "best_model"))
            if self.callback_on_new_best is not None:
                continue_training = self.callback_on_new_best.on_step()
        if self.callback is not None:
            continue_training = continue_training and self._on_event()
        return continue_training
