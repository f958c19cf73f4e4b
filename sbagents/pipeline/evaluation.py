"""Evaluating a trained SB3 model: mean/std return, success rate and env-specific episode metrics.

The summary dict is the ``evaluate --json`` contract (docs/architecture.md); the RLlib backend builds the same
one with :func:`summarize`.
"""

from __future__ import annotations

import functools
from collections import defaultdict
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import VecEnv

from sbagents.callbacks.safety import step_violation
from sbagents.core.env_kinds import EnvKind, GameKind, TeamKind
from sbagents.core.env_names import EnvRef
from sbagents.core.experiment import Experiment
from sbagents.core.options import EvaluateOptions
from sbagents.core.run_dir import LoadedRun
from sbagents.env_factory import make_eval_vec, make_team_vecs, normalize_for_eval, render_modes
from sbagents.errors import UsageError
from sbagents.multiagent.parameter_sharing import SHARED_GROUP
from sbagents.multiagent.team_eval import model_actor, run_team_episodes, slot_agents, team_summary
from sbagents.visualize.text_render import ParallelTextStepPrinter, TextStepPrinter, supports_text


def _episode_metrics_fn(venv: VecEnv) -> Any:
    """The env's ``episode_metrics(step_infos) -> dict`` hook, if it has one."""
    try:
        return venv.get_attr("episode_metrics", [0])[0]
    except AttributeError:
        return None


def summarize(
    env_id: str,
    algo: str,
    returns: Sequence[float],
    lengths: Sequence[int],
    successes: Sequence[bool],
    metrics: dict[str, list[float]],
    costs: Sequence[float] | None = None,
) -> dict[str, Any]:
    """The evaluation summary: ``env``, ``algo``, ``n_episodes``, ``mean_return``, ``std_return``, ``mean_length``,
    ``success_rate`` (None when the env reports no ``is_success``), ``metrics`` (per-episode means) and, for envs
    that report a cost (``info["cost"]`` or ``info["violation"]``), ``mean_cost`` (mean episode cost, EpCost)."""
    cost = {"mean_cost": float(np.mean(costs))} if costs else {}
    return {
        "env": env_id,
        "algo": algo,
        "n_episodes": len(returns),
        "mean_return": float(np.mean(returns)),
        "std_return": float(np.std(returns)),
        "mean_length": float(np.mean(lengths)),
        "success_rate": float(np.mean(successes)) if successes else None,
        "metrics": {k: float(np.mean(v)) for k, v in metrics.items()},
        **cost,
    }


def evaluate_model(
    model: BaseAlgorithm, exp: Experiment, ref: EnvRef, options: EvaluateOptions | None = None,
    stats_path: Path | None = None, trust: bool = False,
) -> dict[str, Any]:
    """Play ``options.n_episodes`` episodes with ``model`` on a fresh env wrapped exactly as in training.

    :param stats_path: saved ``VecNormalize`` statistics of the run (frozen during evaluation).
    :param trust: a legacy pickle of them may be unpickled (``--trust-run``).
    :return: the summary of :func:`summarize` (team returns for multi-agent envs).
    """
    options = options or EvaluateOptions()
    options.validate()
    return _evaluate_kind(ref.kind, model, exp, ref, options, stats_path, trust)


@functools.singledispatch
def _evaluate_kind(kind: EnvKind, model: BaseAlgorithm, exp: Experiment, ref: EnvRef, options: EvaluateOptions,
                   stats_path: Path | None, trust: bool) -> dict[str, Any]:
    """A Gymnasium env: episodes on one reference env (rendered when asked)."""
    if options.opponent is not None:
        raise UsageError(f"--opponent applies to turn-based games; {ref.env_id} is not one")
    text = options.render and supports_text(render_modes(exp, ref))  # labelled text states, else 'human' mode
    extra = {"render_mode": "ansi" if text else "human"} if options.render else {}
    # the reference envs (not the batched ones) render every step
    venv = make_eval_vec(exp, ref, 1, options.seed, stats_path, vec_env="dummy", env_kwargs=extra,
                         wrapper=TextStepPrinter if text else None, trust=trust)
    metrics_fn = _episode_metrics_fn(venv)
    step_infos: list[dict[str, Any]] = []
    successes: list[bool] = []
    metrics: dict[str, list[float]] = defaultdict(list)
    costs: list[float] = []  # episode costs, when the env reports costs
    episode_cost = [0.0, False]  # this episode's cost so far, whether any step had a cost key

    def on_step(locals_: dict[str, Any], _globals: dict[str, Any]) -> None:
        info = locals_["info"]
        step_infos.append(info)
        episode_cost[0] += step_violation(info)[1]
        episode_cost[1] = episode_cost[1] or "cost" in info or "violation" in info
        if locals_["done"]:
            if episode_cost[1]:
                costs.append(float(episode_cost[0]))
            episode_cost[:] = [0.0, False]
            if "is_success" in info:
                successes.append(bool(info["is_success"]))
            if metrics_fn is not None:
                for key, value in metrics_fn(step_infos).items():
                    metrics[key].append(value)
            step_infos.clear()

    try:
        returns, lengths = evaluate_policy(model, venv, n_eval_episodes=options.n_episodes,
                                           deterministic=options.greedy(exp.deterministic_eval),
                                           return_episode_rewards=True,
                                           callback=on_step, warn=False)
    finally:
        venv.close()
    return summarize(ref.env_id, exp.algo, list(returns), list(lengths), successes, metrics,  # type: ignore[arg-type]
                     costs)


@_evaluate_kind.register
def _(kind: TeamKind, model: BaseAlgorithm, exp: Experiment, ref: EnvRef, options: EvaluateOptions,
      stats_path: Path | None, trust: bool) -> dict[str, Any]:
    """A team: whole-team episodes (team return, per-agent returns)."""
    if options.opponent is not None:
        raise UsageError(f"--opponent applies to turn-based games; {ref.env_id} is not one")
    return evaluate_groups({SHARED_GROUP: model}, exp, ref, options, {SHARED_GROUP: stats_path}, trust)


@_evaluate_kind.register
def _(kind: GameKind, model: BaseAlgorithm, exp: Experiment, ref: EnvRef, options: EvaluateOptions,
      stats_path: Path | None, trust: bool) -> dict[str, Any]:
    """A turn-based game: matches against ``options.opponent`` (seats alternating); no attacks or fairness."""
    from sbagents.games.training import evaluate_game

    if options.attacks or options.fairness:
        raise UsageError("--attack and --fairness are not available for turn-based games; --opponent picks who to "
                         "play against")
    return evaluate_game(model, exp, ref, options)


def evaluate_groups(
    models: Mapping[str, BaseAlgorithm], exp: Experiment, ref: EnvRef, options: EvaluateOptions | None = None,
    stats_paths: Mapping[str, Path | None] | None = None, trust: bool = False,
) -> dict[str, Any]:
    """Play ``options.n_episodes`` team episodes of a PettingZoo env, every group acting with its model (one group,
    ``shared``, for parameter sharing), on a fresh team wrapped exactly as in training.

    :param stats_paths: group -> its saved ``VecNormalize`` statistics (frozen during evaluation).
    :param trust: legacy pickles of them may be unpickled (``--trust-run``).
    :return: the summary of :func:`summarize` with team returns and the team metrics
        (:func:`sbagents.multiagent.team_eval.team_summary`).
    """
    options = options or EvaluateOptions()
    options.validate()
    text = options.render and supports_text(render_modes(exp, ref))  # labelled text states, else 'human' mode
    extra = {"render_mode": "ansi" if text else "human"} if options.render else {}
    venvs = make_team_vecs(exp, ref, 1, None, vec_env="dummy", env_kwargs=extra,
                           wrapper=ParallelTextStepPrinter if text else None)
    venvs = {g: normalize_for_eval(v, exp, (stats_paths or {}).get(g), trust) for g, v in venvs.items()}
    try:
        actors = {g: model_actor(models[g], options.greedy(exp.deterministic_eval)) for g in venvs}
        episodes = run_team_episodes(venvs, actors, options.n_episodes, options.seed)
    finally:
        for venv in venvs.values():
            venv.close()
    groups = {g: slot_agents(v, g) for g, v in venvs.items()}
    return {"env": ref.env_id, "algo": exp.algo, **team_summary(episodes, groups)}


def evaluate_sb3_run(run: LoadedRun, options: EvaluateOptions) -> dict[str, Any]:
    """``python -m sbagents.evaluate`` on a finished SB3 run: the summary, plus ``adversarial`` / ``fairness``
    results (and their CSV + PNG files in the run dir) when the options ask for attacks or fairness."""
    from sbagents.pipeline.trust import trust_report

    if len(run.models) > 1:
        if options.attacks or options.fairness:
            raise UsageError("--attack and --fairness evaluate one model; this run has one model per group")
        return evaluate_groups(run.models, run.experiment, run.env, options, run.stats_paths, run.trust)
    summary = evaluate_model(run.model, run.experiment, run.env, options, run.stats_path, run.trust)
    if options.attacks or options.fairness:
        summary.update(trust_report(run, options))
    return summary
