"""Evaluating a trained SB3 model: mean/std return, success rate and env-specific episode metrics.

The summary dict is the ``evaluate --json`` contract (docs/architecture.md); the RLlib backend builds the same
one with :func:`summarize`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecEnv

from sbagents.callbacks.episodes import (
    EpisodeRecord,
    Policy,
    episode_metrics_of,
    model_actor,
    play_episodes,
    summarize_records,
)
from sbagents.core.env_kinds import EnvKind, GameKind, TeamKind, kind_operation
from sbagents.core.env_names import EnvRef
from sbagents.core.experiment import Experiment
from sbagents.core.options import EvaluateOptions
from sbagents.core.run_dir import LoadedRun
from sbagents.env_construction import render_modes
from sbagents.env_factory import make_eval_vec, make_team_vecs, normalize_for_eval
from sbagents.errors import UsageError
from sbagents.multiagent.team_eval import run_team_episodes, slot_agents, team_summary
from sbagents.visualize.text_render import ParallelTextStepPrinter, TextStepPrinter, supports_text


def summarize(
    env_id: str,
    algo: str,
    returns: Sequence[float],
    lengths: Sequence[int],
    successes: Sequence[bool],
    metrics: Mapping[str, Sequence[float]],
    costs: Sequence[float] | None = None,
) -> dict[str, Any]:
    """The evaluation summary from per-episode lists (``successes``, each metric's values and ``costs`` may cover
    fewer episodes): ``env``, ``algo`` and :func:`~sbagents.callbacks.episodes.summarize_records` (``n_episodes``,
    ``mean_return``, ``std_return``, ``mean_length``, ``success_rate`` (None when the env reports no
    ``is_success``), ``metrics`` (per-episode means) and ``mean_cost`` (mean episode cost, EpCost) for envs that
    report a cost)."""
    costs = costs or []
    records = [
        EpisodeRecord(float(ret), int(length), bool(successes[i]) if i < len(successes) else None,
                      cost=float(costs[i]) if i < len(costs) else None,
                      metrics={k: v[i] for k, v in metrics.items() if i < len(v)})
        for i, (ret, length) in enumerate(zip(returns, lengths, strict=True))
    ]
    return {"env": env_id, "algo": algo, **summarize_records(records)}


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


@kind_operation()
def _evaluate_kind(kind: EnvKind, model: BaseAlgorithm, exp: Experiment, ref: EnvRef, options: EvaluateOptions,
                   stats_path: Path | None, trust: bool) -> dict[str, Any]:
    """A Gymnasium env: episodes on one reference env (rendered when asked)."""
    if options.opponent is not None:
        raise UsageError(f"--opponent applies to turn-based games; {ref.env_id} is not one")
    greedy = options.greedy(exp.deterministic_eval)
    return _play_one(exp, ref, options, lambda venv: model_actor(model, greedy), stats_path, trust)


def _play_one(exp: Experiment, ref: EnvRef, options: EvaluateOptions, actor_for: Callable[[VecEnv], Policy],
              stats_path: Path | None = None, trust: bool = False) -> dict[str, Any]:
    """Episodes of one agent on a reference env (rendered when asked), acting with ``actor_for(venv)``: the
    summary."""
    text = options.render and supports_text(render_modes(exp, ref))  # labelled text states, else 'human' mode
    extra = {"render_mode": "ansi" if text else "human"} if options.render else {}
    # the reference envs (not the batched ones) render every step
    venv = make_eval_vec(exp, ref, 1, options.seed, stats_path, vec_env="dummy", env_kwargs=extra,
                         wrapper=TextStepPrinter if text else None, trust=trust)
    try:
        records = play_episodes(venv, actor_for(venv), options.n_episodes, monitor_episodes=True,
                                episode_metrics=episode_metrics_of(venv))
    finally:
        venv.close()
    return {"env": ref.env_id, "algo": exp.algo, **summarize_records(records)}


@_evaluate_kind.register
def _team_evaluate_kind(kind: TeamKind, model: BaseAlgorithm, exp: Experiment, ref: EnvRef, options: EvaluateOptions,
                        stats_path: Path | None, trust: bool) -> dict[str, Any]:
    """A team: whole-team episodes (team return, per-agent returns)."""
    if options.opponent is not None:
        raise UsageError(f"--opponent applies to turn-based games; {ref.env_id} is not one")
    greedy = options.greedy(exp.deterministic_eval)  # the run's one model acts for its one group, whatever its name
    return _play_team(exp, ref, options, lambda group, venv: model_actor(model, greedy), lambda group: stats_path,
                      trust)


@_evaluate_kind.register
def _game_evaluate_kind(kind: GameKind, model: BaseAlgorithm, exp: Experiment, ref: EnvRef, options: EvaluateOptions,
                        stats_path: Path | None, trust: bool) -> dict[str, Any]:
    """A turn-based game: matches against ``options.opponent`` (seats alternating); no attacks or fairness."""
    if options.attacks or options.fairness:
        raise UsageError("--attack and --fairness are not available for turn-based games; --opponent picks who to "
                         "play against")
    return game_operations().evaluate_game(model, exp, ref, options)


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
    greedy = options.greedy(exp.deterministic_eval)
    return _play_team(exp, ref, options, lambda group, venv: model_actor(models[group], greedy),
                      lambda group: (stats_paths or {}).get(group), trust)


def _play_team(exp: Experiment, ref: EnvRef, options: EvaluateOptions, actor_for: Callable[[str, VecEnv], Policy],
               stats_for: Callable[[str], Path | None] = lambda group: None, trust: bool = False) -> dict[str, Any]:
    """Team episodes on a fresh team (rendered when asked), each group acting with ``actor_for(group, venv)`` under
    the statistics ``stats_for(group)``: the summary with team returns."""
    text = options.render and supports_text(render_modes(exp, ref))  # labelled text states, else 'human' mode
    extra = {"render_mode": "ansi" if text else "human"} if options.render else {}
    venvs = make_team_vecs(exp, ref, 1, None, vec_env="dummy", env_kwargs=extra,
                           wrapper=ParallelTextStepPrinter if text else None)
    venvs = {g: normalize_for_eval(v, exp, stats_for(g), trust) for g, v in venvs.items()}
    try:
        actors = {g: actor_for(g, v) for g, v in venvs.items()}
        episodes = run_team_episodes(venvs, actors, options.n_episodes, options.seed)
    finally:
        for venv in venvs.values():
            venv.close()
    groups = {g: slot_agents(v, g) for g, v in venvs.items()}
    return {"env": ref.env_id, "algo": exp.algo, **team_summary(episodes, groups)}


#: The baselines :func:`evaluate_baseline` plays.
BASELINES = ("random", "scripted")


def evaluate_baseline(ref: EnvRef, policy: str, options: EvaluateOptions | None = None,
                      env_kwargs: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Evaluate a baseline policy on the plain env ``ref`` (no wrappers, no normalization), without a run:
    ``random`` (uniform actions; a game's random legal moves) or ``scripted`` (the env's expert,
    :data:`sbagents.registration.SCRIPTED_POLICIES`; a game's best built-in opponent). The summary's ``algo`` is the
    policy's name (``evaluate --policy``).

    :raises UsageError: another policy name, or ``scripted`` for an env without an expert.
    """
    exp = baseline_experiment(ref, policy, env_kwargs)
    options = options or EvaluateOptions()
    options.validate()
    return _baseline_kind(ref.kind, policy, exp, ref, options)


def baseline_experiment(ref: EnvRef, policy: str, env_kwargs: Mapping[str, Any] | None = None,
                        entry: Mapping[str, Any] | None = None) -> Experiment:
    """The experiment a baseline plays: the plain env ``ref`` (no wrappers, no normalization, the kind's options of
    the config entry ``entry``: default none, e.g. ``{"policies": "per_group"}`` for a team) with ``env_kwargs``; its
    ``algo`` is the policy's name.

    :raises UsageError: a policy other than :data:`BASELINES`.
    """
    if policy not in BASELINES:
        raise UsageError(f"--policy {policy!r}: accepted: {', '.join(BASELINES)}")
    return Experiment(algo=policy, env_id=ref.env_id, n_timesteps=0, env_kwargs=dict(env_kwargs or {}),
                      env_kind=ref.kind, kind_options=ref.kind.options(dict(entry or {}), f"--policy {policy}"))


def baseline_actor(policy: str, env_id: str, venv: VecEnv, seed: int | None) -> Policy:
    """The actor of ``policy`` in ``venv``: uniform random actions, or one expert controller per copy."""
    from sbagents.baselines.policies import RandomPolicy, scripted_policy

    if policy == "random":
        return model_actor(RandomPolicy(venv.action_space, seed))
    return model_actor(scripted_policy(env_id, venv))


@kind_operation()
def _baseline_kind(kind: EnvKind, policy: str, exp: Experiment, ref: EnvRef, options: EvaluateOptions
                   ) -> dict[str, Any]:
    """A Gymnasium env: episodes on one reference env."""
    if options.opponent is not None:
        raise UsageError(f"--opponent applies to turn-based games; {ref.env_id} is not one")
    return _play_one(exp, ref, options, lambda venv: baseline_actor(policy, ref.env_id, venv, options.seed))


@_baseline_kind.register
def _team_baseline_kind(kind: TeamKind, policy: str, exp: Experiment, ref: EnvRef, options: EvaluateOptions
                        ) -> dict[str, Any]:
    """A team: every agent acts with the baseline (each group's copies)."""
    if options.opponent is not None:
        raise UsageError(f"--opponent applies to turn-based games; {ref.env_id} is not one")
    return _play_team(exp, ref, options,
                      lambda group, venv: baseline_actor(policy, ref.env_id, venv, options.seed))


@_baseline_kind.register
def _game_baseline_kind(kind: GameKind, policy: str, exp: Experiment, ref: EnvRef, options: EvaluateOptions
                        ) -> dict[str, Any]:
    """A turn-based game: the baseline plays the learner's seats against ``options.opponent`` (default: random)."""
    return game_operations().evaluate_game_baseline(policy, exp, ref, options)


def game_operations() -> ModuleType:
    """The turn-based games' evaluation and recording (:mod:`sbagents.games.training`, which also holds
    :func:`sbagents.games.recording.record_games`), imported when a game is evaluated or recorded."""
    from sbagents.games import training

    return training


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
