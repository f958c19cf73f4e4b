"""Team evaluation: :func:`run_team_episodes` (the one runner of team episodes, for one shared model, one model per
group, or RLlib's modules), :func:`evaluate_team` and :class:`TeamEvalCallback`.

Team return = the sum of all agents' rewards over an episode; one result per team episode. A team episode ends when
the first group's VecEnv reports SB3's ``episode`` info on its first slot (agents may end earlier). Episodes are
played and summarized by :mod:`sbagents.callbacks.episodes` (``model_actor`` is re-exported from there).
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from pettingzoo import ParallelEnv
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.vec_env import VecEnv, sync_envs_normalization

from sbagents.atomic import save_model, write_npz
from sbagents.callbacks.episodes import EpisodeRecord, Policy, model_actor, play_episodes, stateless, summarize_records
from sbagents.callbacks.episodes import slot_agents as episode_slot_agents
from sbagents.core.run_dir import best_stats_name
from sbagents.multiagent.competition import sums_to_zero
from sbagents.multiagent.parameter_sharing import SHARED_GROUP, ParameterSharingVecEnv
from sbagents.state_files import save_vecnormalize

#: ``obs batch -> actions`` (a stateless actor; :func:`~sbagents.callbacks.episodes.stateless` makes it a ``Policy``).
Actor = Callable[[Any], np.ndarray]
#: The former name of :class:`~sbagents.callbacks.episodes.EpisodeRecord`.
EpisodeResult = EpisodeRecord


def slot_agents(venv: VecEnv, default: str) -> list[str]:
    """The agents behind a team VecEnv's slots (one copy), or ``[default]`` for a plain VecEnv."""
    return episode_slot_agents(venv) or [default]


def run_team_episodes(
    venvs: Mapping[str, VecEnv], actors: Mapping[str, Policy], n_episodes: int, seed: int | None = None
) -> list[EpisodeRecord]:
    """Play ``n_episodes`` team episodes on the group VecEnvs of one team (a single VecEnv for a shared policy),
    every group acting with its actor (:func:`~sbagents.callbacks.episodes.play_episodes`).

    Rewards are unnormalized; each ``VecNormalize`` is frozen meanwhile.

    :param venvs: group -> its VecEnv (they step one team together), in the team's group order.
    :param actors: group -> its :class:`~sbagents.callbacks.episodes.Policy` (its hidden state is kept per slot and
        reset where that slot's agent starts an episode).
    :param seed: seed of the first reset (then the env's RNG continues) -> reproducible returns.
    :return: per episode: team return, length, ``is_success``, violation steps and cost (every agent's), the first
        slot's last ``info``, each agent's return and the env's declared metrics.
    """
    return play_episodes(venvs, actors, n_episodes, seed, team=True)


def team_summary(episodes: Sequence[EpisodeRecord], groups: Mapping[str, Sequence[str]] | None = None
                 ) -> dict[str, Any]:
    """:func:`~sbagents.callbacks.episodes.summarize_records` of team episodes: ``n_episodes``,
    ``mean_return``/``std_return`` (team return = sum over agents), ``mean_length``, ``success_rate`` and
    ``metrics``: ``episode_length``, ``per_agent_return``, ``per_group_return`` (with several ``groups``) and the
    means of the env's declared episode metrics (``metadata["info_metrics"]``, carried in the team's ``episode``
    info), and ``note`` when the agents of one shared policy compete (:func:`competition_note`)."""
    summary = summarize_records(episodes, groups)
    note = competition_note(episodes) if groups is None or len(groups) <= 1 else None
    if note is not None:
        summary["note"] = note
    return summary


def competition_note(episodes: Sequence[EpisodeRecord]) -> str | None:
    """One line when the agents' returns sum to zero in every episode (and are not all zero): they compete, so a
    team return is zero by construction (``rps_v2``) and one shared policy plays both sides; None otherwise."""
    returns = [list(e.agent_returns.values()) for e in episodes if e.agent_returns]
    if not returns or len(returns) < len(episodes) or min(len(r) for r in returns) < 2:
        return None
    zero_sum = all(sums_to_zero(r) for r in returns)
    if not zero_sum or not any(x != 0 for r in returns for x in r):
        return None
    return ("its agents compete: their returns sum to 0 in every episode, so the team return is 0 by construction; "
            "train one model per side with -params policies:per_agent and compare metrics.per_agent_return")


def evaluate_team(
    model: Any,
    env: VecEnv | Callable[[], ParallelEnv],
    n_episodes: int = 10,
    deterministic: bool = True,
    seed: int | None = None,
    act: Actor | None = None,
) -> dict[str, Any]:
    """Play ``n_episodes`` team episodes of one shared policy (one team copy) and summarize them.

    :param model: an SB3 model (``predict``), or None with ``act``.
    :param env: a one-copy parameter-sharing VecEnv (under a frozen ``VecNormalize`` when the run normalized), or
        a zero-argument ``ParallelEnv`` constructor (a team VecEnv is built and closed here).
    :param act: maps an observation batch ``(n_agents, *obs_shape)`` to actions (default ``model.predict``).
    :return: :func:`team_summary` of the episodes.
    """
    actor = stateless(act) if act is not None else model_actor(model, deterministic)
    venv = env if isinstance(env, VecEnv) else ParameterSharingVecEnv([env])
    try:
        return team_summary(run_team_episodes({SHARED_GROUP: venv}, {SHARED_GROUP: actor}, n_episodes, seed))
    finally:
        if venv is not env:
            venv.close()


class TeamEvalCallback(EvalCallback):
    """``EvalCallback`` that scores the team (every group's model acting) every ``eval_freq`` calls.

    Keeps the best models (highest mean team return; ``best_model.zip``, or ``best_model.<group>.zip`` per group) in
    ``best_model_save_path`` and writes ``evaluations.npz`` in EvalCallback's format (``timesteps``, ``results`` team
    returns of shape ``(n_evals, n_eval_episodes)``, ``ep_lengths``, ``successes``) to ``log_path``. Logs
    ``eval/mean_reward``, ``eval/mean_ep_length``, ``eval/success_rate`` and ``eval/<metric>`` for the env's declared
    metrics.

    :param eval_env: the evaluation team: one VecEnv (a shared policy, this callback's model) or group -> VecEnv of
        one team; their ``VecNormalize`` statistics are synced from the training envs before every evaluation.
    :param models: group -> model, when there are several groups (the model this callback runs in is one of them).
    :param eval_freq: evaluate every ``eval_freq`` calls of ``_on_step`` (i.e. vec steps, not env steps).
    :param seed: seed of each evaluation (the same episodes every time; ``None``: fresh ones).
    :param timestep_scale: run timesteps per timestep of this callback's model (in ``evaluations.npz``): with one
        model per group, the team's agents per agent of the first group.
    """

    def __init__(
        self,
        eval_env: VecEnv | Mapping[str, VecEnv],
        n_eval_episodes: int = 5,
        eval_freq: int = 10000,
        log_path: str | None = None,
        best_model_save_path: str | None = None,
        deterministic: bool = True,
        seed: int | None = None,
        models: Mapping[str, BaseAlgorithm] | None = None,
        callback_after_eval: Any = None,
        verbose: int = 1,
        timestep_scale: float = 1.0,
    ) -> None:
        self.eval_envs = dict(eval_env) if isinstance(eval_env, Mapping) else {SHARED_GROUP: eval_env}
        super().__init__(next(iter(self.eval_envs.values())), callback_after_eval=callback_after_eval,
                         n_eval_episodes=n_eval_episodes, eval_freq=eval_freq, log_path=log_path,
                         best_model_save_path=best_model_save_path, deterministic=deterministic, verbose=verbose,
                         warn=False)
        self.group_models = dict(models) if models is not None else None
        self.eval_seed = seed
        self.timestep_scale = timestep_scale
        self.last_result: dict[str, Any] = {}

    def _init_callback(self) -> None:
        with warnings.catch_warnings():  # the eval env is the reference VecEnv; the training one may be batched
            warnings.filterwarnings("ignore", message="Training and eval env are not of the same type")
            super()._init_callback()

    def _models(self) -> dict[str, BaseAlgorithm]:
        return self.group_models if self.group_models is not None else {SHARED_GROUP: self.model}

    def _on_step(self) -> bool:
        if self.eval_freq <= 0 or self.n_calls % self.eval_freq != 0:
            return True
        models = self._models()
        for group, venv in self.eval_envs.items():
            if models[group].get_vec_normalize_env() is not None:  # as SB3's EvalCallback: only what normalizes
                sync_envs_normalization(models[group].get_env(), venv)  # type: ignore[arg-type]
        actors = {g: model_actor(m, self.deterministic) for g, m in models.items()}
        episodes = run_team_episodes(self.eval_envs, actors, self.n_eval_episodes, self.eval_seed)
        groups = {g: slot_agents(v, g) for g, v in self.eval_envs.items()}
        self.last_result = team_summary(episodes, groups)
        self.evaluations_timesteps.append(round(self.num_timesteps * self.timestep_scale))
        self.evaluations_results.append([e.ret for e in episodes])
        self.evaluations_length.append([e.length for e in episodes])
        self._is_success_buffer = [bool(e.success) for e in episodes if e.success is not None]
        self.evaluations_successes.append(self._is_success_buffer)
        if self.log_path is not None:
            write_npz(f"{self.log_path}.npz", timesteps=self.evaluations_timesteps, results=self.evaluations_results,
                      ep_lengths=self.evaluations_length, successes=self.evaluations_successes)
        mean_reward = float(self.last_result["mean_return"])
        self.last_mean_reward = mean_reward
        self.logger.record("eval/mean_reward", mean_reward)
        self.logger.record("eval/mean_ep_length", float(self.last_result["mean_length"]))
        if self.last_result["success_rate"] is not None:
            self.logger.record("eval/success_rate", float(self.last_result["success_rate"]))
        for key, value in self.last_result["metrics"].items():
            if isinstance(value, float) and key != "episode_length":
                self.logger.record(f"eval/{key}", value)
        self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
        self.logger.dump(self.num_timesteps)
        if mean_reward > self.best_mean_reward:
            self.best_mean_reward = mean_reward
            if self.best_model_save_path is not None:
                for group, model in models.items():  # statistics first: a best model has its own beside it
                    stats = model.get_vec_normalize_env()
                    if stats is not None:
                        save_vecnormalize(stats, Path(self.best_model_save_path) / best_stats_name(group))
                    name = "best_model.zip" if group == SHARED_GROUP else f"best_model.{group}.zip"
                    save_model(model, os.path.join(self.best_model_save_path, name))
        return self._on_event() if self.callback is not None else True
