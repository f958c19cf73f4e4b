"""Team evaluation of a parameter-shared policy: :func:`evaluate_team` and :class:`TeamEvalCallback`.

Team return = the sum of all agents' rewards over an episode; one result per team episode.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
from pettingzoo import ParallelEnv
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.vec_env import VecNormalize

from sbagents.multiagent import ParameterSharingVecEnv


def evaluate_team(
    model: Any,
    env_fn: Callable[[], ParallelEnv],
    n_episodes: int = 10,
    deterministic: bool = True,
    seed: int | None = None,
    render: bool = False,
    vec_normalize: VecNormalize | None = None,
) -> dict[str, Any]:
    """Run ``n_episodes`` team episodes (one env, sequentially) with a parameter-shared policy.

    :param model: anything with SB3's ``predict(obs, deterministic=...)``.
    :param env_fn: zero-argument constructor of the ``ParallelEnv``.
    :param seed: seed of the first reset (then the env's RNG continues) -> reproducible returns.
    :param render: call the env's ``render()`` every step (create it with a ``render_mode``).
    :param vec_normalize: if given, observations are normalized with its (frozen) statistics.
    :return: ``n_episodes``, ``mean_return``/``std_return`` (team return = sum over agents),
        ``mean_length``, ``success_rate`` (share of episodes with ``is_success``) and
        ``metrics`` = ``{"treasures_per_episode", "team_return"}`` (NaN treasures if the env reports none).
    """
    ep = _run_team_episodes(model, env_fn, n_episodes, deterministic, seed, render, vec_normalize)
    return _summary(ep)


def _run_team_episodes(
    model: Any,
    env_fn: Callable[[], ParallelEnv],
    n_episodes: int,
    deterministic: bool,
    seed: int | None,
    render: bool,
    vec_normalize: VecNormalize | None,
) -> dict[str, list[Any]]:
    """Per-episode ``returns``, ``lengths``, ``successes``, ``treasures`` (see :func:`evaluate_team`)."""
    vec = ParameterSharingVecEnv([env_fn])
    if seed is not None:
        vec.seed(seed)
    ep: dict[str, list[Any]] = {"returns": [], "lengths": [], "successes": [], "treasures": []}
    obs: Any = vec.reset()
    try:
        while len(ep["returns"]) < n_episodes:
            if vec_normalize is not None:
                obs = vec_normalize.normalize_obs(obs)
            actions, _ = model.predict(obs, deterministic=deterministic)
            obs, _, dones, infos = vec.step(actions)
            if render:
                vec.envs[0].render()
            if dones[0]:
                info = infos[0]
                ep["returns"].append(float(info["episode"]["r"]))
                ep["lengths"].append(int(info["episode"]["l"]))
                ep["successes"].append(bool(info.get("is_success", False)))
                ep["treasures"].append(float(info.get("treasures", np.nan)))
    finally:
        vec.close()
    return ep


def _summary(ep: dict[str, list[Any]]) -> dict[str, Any]:
    returns = ep["returns"]
    return {
        "n_episodes": len(returns),
        "mean_return": float(np.mean(returns)),
        "std_return": float(np.std(returns)),
        "mean_length": float(np.mean(ep["lengths"])),
        "success_rate": float(np.mean(ep["successes"])),
        "metrics": {
            "treasures_per_episode": float(np.mean(ep["treasures"])),
            "team_return": float(np.mean(returns)),
        },
    }


class TeamEvalCallback(EvalCallback):
    """``EvalCallback`` that scores the team with :func:`evaluate_team` every ``eval_freq`` calls.

    Keeps ``best_model.zip`` (highest mean team return) in ``best_model_save_path`` and writes
    ``evaluations.npz`` in EvalCallback's format (``timesteps``, ``results`` team returns of shape
    ``(n_evals, n_eval_episodes)``, ``ep_lengths``, ``successes``) to ``log_path``. Logs ``eval/mean_reward``,
    ``eval/mean_ep_length``, ``eval/success_rate`` and ``eval/treasures_per_episode``.

    :param env_fn: zero-argument constructor of the evaluation ``ParallelEnv``.
    :param eval_freq: evaluate every ``eval_freq`` calls of ``_on_step`` (i.e. vec steps, not env steps).
    :param seed: seed of each evaluation (the same episodes every time; ``None``: fresh ones).
    """

    def __init__(
        self,
        env_fn: Callable[[], ParallelEnv],
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
            ParameterSharingVecEnv([env_fn]),
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
        self.env_fn = env_fn
        self.eval_seed = seed
        self.last_result: dict[str, Any] = {}
        self._returns: list[list[float]] = []

    def _init_callback(self) -> None:
        with warnings.catch_warnings():  # the eval env is the reference VecEnv; the training one may be batched
            warnings.filterwarnings("ignore", message="Training and eval env are not of the same type")
            super()._init_callback()

    def _on_step(self) -> bool:
        if self.eval_freq <= 0 or self.n_calls % self.eval_freq != 0:
            return True
        vec_norm = self.model.get_vec_normalize_env()
        result = _run_team_episodes(
            self.model, self.env_fn, self.n_eval_episodes, self.deterministic, self.eval_seed, False, vec_norm
        )
        self.last_result = _summary(result)
        self.evaluations_timesteps.append(self.num_timesteps)
        self.evaluations_results.append(result["returns"])
        self.evaluations_length.append(result["lengths"])
        self._is_success_buffer = list(result["successes"])
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
        if self.verbose >= 1:
            print(
                f"Eval num_timesteps={self.num_timesteps}, team return={mean_reward:.2f}, "
                f"treasures={self.last_result['metrics']['treasures_per_episode']:.2f}"
            )
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
