"""Training with SB3: :func:`train_sb3`, the SB3 backend of ``python -m sbagents.train``.

Flow (docs/architecture.md): :class:`TrainSpec` + zoo config -> :class:`Experiment` -> env factory -> SB3 model +
callbacks -> run directory. Every run checks what it can before the run dir is created (a run of one model per group
builds one team copy to check its groups' spaces); a setup failure removes the half-made run dir; an interrupted run
(Ctrl-C, SIGTERM) still saves its models and logs. One model or one per group of a team's agents, it is the same
sequence: the models of a run of one model per group learn in lockstep on one team
(:func:`sbagents.multiagent.lockstep.learn_in_lockstep`), and every step of the sequence runs for each of them.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sbagents.atari.envpool_support import training_vec_env
from sbagents.atomic import save_model
from sbagents.callbacks.run_files import AtomicCheckpointCallback
from sbagents.core.env_names import EnvRef, resolve_env
from sbagents.core.experiment import Experiment, build_experiment
from sbagents.core.extensions import ActiveExtension, ExtensionPlan, activate, prepare_extensions
from sbagents.core.lifecycle import (
    LearningClock,
    SummaryItems,
    TrainResult,
    base_summary,
    default_command,
    draw_seed,
    finish_run,
    new_run_dir,
)
from sbagents.core.options import EvalOptions, EvaluateOptions, ExecOptions, OutputOptions, Sb3Options, TrainSpec
from sbagents.core.progress import ProgressReporter
from sbagents.core.run_dir import (
    BEST_MODEL_FILE,
    CHECKPOINT_PREFIX,
    SHARED_GROUP,
    best_stats_path,
    check_model_file,
    checkpoint_stats_path,
    env_stem,
    group_model_name,
    group_resume_files,
    group_stats_name,
)
from sbagents.env_factory import make_team_vecs, make_vec, normalize_for_training
from sbagents.errors import UsageError
from sbagents.multiagent.lockstep import learn_in_lockstep
from sbagents.pipeline.budget import budget_warnings
from sbagents.pipeline.console import EvalReportCallback, ProgressCallback
from sbagents.pipeline.evaluation import evaluate_groups, evaluate_model
from sbagents.pipeline.kinds import model_callbacks, model_groups, periodic_evaluation, training_env_kwargs
from sbagents.pipeline.models import Resume, RunContext, check_group_spaces, check_spaces, make_model
from sbagents.replay.buffer_files import checkpoint_steps
from sbagents.state_files import VECNORMALIZE_FILE, save_vecnormalize


class StopOnRequestCallback(BaseCallback):
    """Ends ``learn`` between two steps once ``clock.stop_requested`` (the first Ctrl-C / SIGTERM of a graceful
    :class:`~sbagents.core.lifecycle.LearningClock`)."""

    def __init__(self, clock: LearningClock) -> None:
        super().__init__(verbose=0)
        self.clock = clock

    def _on_step(self) -> bool:
        return not self.clock.stop_requested


def train_sb3(
    spec: TrainSpec,
    output: OutputOptions | None = None,
    evaluation: EvalOptions | None = None,
    execution: ExecOptions | None = None,
    callbacks: Sequence[BaseCallback] = (),
    features: Sequence[Any] = (),
    sb3: Sb3Options | None = None,
) -> TrainResult:
    """Train ``spec.algo`` on ``spec.env`` with SB3 and its zoo config, and write a run directory.

    One fixed sequence for every run: :func:`_plan` (every check, before a run dir exists), then :func:`_build`
    (run dir, envs, models, callbacks), :func:`_learn` and :func:`_finish` (summary, final evaluation). A run trains
    one model, or one model per group of a team's agents (``policies: per_group | per_agent``), which learn in
    lockstep on one team; the training extensions take part through their hooks at each step, for each model.

    :param callbacks: extra SB3 callbacks, after sbagents' own (in the first group's model when there are several).
    :param features: the specs of the training extensions this run uses (:mod:`sbagents.extensions`: e.g.
        ``TrustOptions``, ``PrivacyOptions``, a ``RobustSpec``), each checked by its extension.
    :param sb3: the vec env and the log interval.
    :return: the run dir, the model and the summary; ``interrupted`` is True after Ctrl-C/SIGTERM.
    """
    run = _plan(spec, output or OutputOptions(), evaluation or EvalOptions(), execution or ExecOptions(),
                sb3 or Sb3Options(), features)
    built = _build(run)
    clock = _learn(run, built, callbacks)
    return _finish(run, built, clock)


@dataclass
class _RunPlan:
    """A checked run, before its run dir exists: the options, the env, the experiment, the run's extensions (configured,
    with their contributions: :func:`~sbagents.extensions.prepare_extensions`), and what ``args.yml`` records."""

    spec: TrainSpec
    output: OutputOptions
    evaluation: EvalOptions
    execution: ExecOptions
    sb3: Sb3Options
    ref: EnvRef
    exp: Experiment
    groups: dict[str, list[str]] | None
    actives: list[ActiveExtension]
    seed: int
    eval_freq: int
    vec_env: str
    resumes: dict[str | None, Resume]
    args: dict[str, Any]
    command: str

    @property
    def per_group(self) -> bool:
        """Whether the run trains one model per group (several groups)."""
        return self.groups is not None and len(self.groups) > 1

    @property
    def n_agents(self) -> int:
        """The team's agents (1 for a Gymnasium env)."""
        return sum(len(a) for a in self.groups.values()) if self.groups is not None else 1


def _plan(spec: TrainSpec, output: OutputOptions, evaluation: EvalOptions, execution: ExecOptions,
          sb3: Sb3Options, features: Sequence[Any]) -> _RunPlan:
    """Check everything that can be checked before a run dir exists (one-line :class:`UsageError` otherwise)."""
    for group in (spec, evaluation, execution, sb3):
        group.validate()
    actives = activate(features)  # each spec's own values checked
    if execution.num_threads > 0:
        torch.set_num_threads(execution.num_threads)
    ref = resolve_env(spec.env, spec.gym_packages)
    exp = build_experiment(spec, ref, tuple(a.extension.overrides_key for a in actives if a.extension.overrides_key))
    if exp.n_timesteps == 0:
        raise UsageError(f"no n_timesteps for {spec.algo} on {ref.env_id} in its config; pass -n N")
    groups = model_groups(ref.kind, exp, ref)
    plan = ExtensionPlan(spec.algo, exp, ref, resuming=spec.trained_agent is not None,
                         n_models=1 if groups is None else len(groups),
                         groups=tuple(groups) if groups is not None and len(groups) > 1 else (),
                         specs={a.name: a.spec for a in actives},
                         hyperparams=spec.hyperparams)
    actives = prepare_extensions(plan)
    exp = plan.exp
    per_group = groups is not None and len(groups) > 1
    if per_group:
        refused = [a.extension.flags for a in actives if not a.extension.group_runs]
        if refused:
            raise UsageError(f"{', '.join(refused)} not supported for runs of one model per group ({ref.env_id})")
        check_group_spaces(exp, ref)
    else:
        check_spaces(exp, ref)
    agent_path = check_model_file(spec.trained_agent) if spec.trained_agent is not None else None
    resumes: dict[str | None, Resume] = {}
    if agent_path is not None and per_group:  # one group's model names them all: each continues
        assert groups is not None
        for name, (path, stats) in group_resume_files(agent_path, ref.env_id, list(groups)).items():
            resumes[name] = Resume(check_model_file(path), spec.trust_run, stats)
    elif agent_path is not None:
        resumes[None] = Resume(agent_path, spec.trust_run, _resume_stats(agent_path))
    seed = draw_seed(execution.seed)
    vec_env = training_vec_env(sb3.vec_env, exp, ref)  # auto: EnvPool for Atari ids when installed
    eval_freq = evaluation.frequency(exp.n_timesteps)
    args = {"algo": spec.algo, "env": ref.env_id, "seed": seed, "n_timesteps": exp.n_timesteps,
            "log_folder": str(output.log_folder), "eval_freq": eval_freq,
            "eval_episodes": evaluation.eval_episodes, "vec_env": vec_env, "device": execution.device,
            "trained_agent": str(agent_path) if agent_path else None}
    for active in actives:
        args.update(active.extension.record(active.spec).args)
    if groups is not None:  # the team's agents per step: plots convert team steps to timesteps with it
        args.update(groups=groups, timesteps_per_env_step=sum(len(a) for a in groups.values()))
    return _RunPlan(spec, output, evaluation, execution, sb3, ref, exp, groups, actives, seed, eval_freq, vec_env,
                    resumes, args,
                    output.command or default_command(spec, execution, actives))


@dataclass
class _Model:
    """One model of a run: its context (what the extensions' hooks see), sbagents' own callbacks, the extensions'
    callbacks (in extension order) and, once learning stopped, each extension's ``summary.json`` items (in extension
    order)."""

    ctx: RunContext
    own: list[BaseCallback]
    extension_callbacks: list[BaseCallback]
    items: list[dict[str, Any]] = field(default_factory=list)


@dataclass
class _BuiltRun:
    """An SB3 run ready to learn: its models (one, or one per group in the team's order), reporter and the team
    coordinator that steps the models of a run of one model per group together.

    :param joint: the team coordinator (None: the run's one model learns alone).
    :param env_steps: team steps of the run's models in lockstep (0: one model).
    """

    models: list[_Model]
    reporter: ProgressReporter
    steps_before: int
    warnings: list[str]
    joint: Any = None
    env_steps: int = 0


def _resume_stats(model: Path) -> Path:
    """The VecNormalize statistics saved with the model ``-i`` continues: a checkpoint's own
    (``rl_model_vecnormalize_<N>_steps.npz``), ``best_model.zip``'s (``vecnormalize_best.npz``), else the run dir's
    (those of its final model)."""
    steps = checkpoint_steps(model)
    if steps is not None:
        return checkpoint_stats_path(model.parent, steps)
    return best_stats_path(model.parent) if model.name == BEST_MODEL_FILE else model.parent / VECNORMALIZE_FILE


def _resumed(run: _RunPlan, group: str | None) -> Path | None:
    """The model file ``-i`` continues for the model of ``group`` (None: a new model)."""
    resume = run.resumes.get(group)
    return resume.path if resume is not None else None


def _train_envs(run: _RunPlan, run_dir: Path) -> tuple[dict[str | None, VecEnv], Any]:
    """The training VecEnv of each model (``None``: the run's one model; else each group's, stepping one team) with
    its normalization, and the team coordinator of the groups (None for one model)."""
    exp, ref = run.exp, run.ref

    def stats(group: str | None) -> Path | None:
        resume = run.resumes.get(group)
        return resume.stats if resume is not None else None

    if not run.per_group:
        venv = make_vec(exp, ref, exp.n_envs, run.seed, run_dir, run.vec_env,
                        env_kwargs=training_env_kwargs(ref.kind, exp, ref, run_dir))
        return {None: normalize_for_training(venv, exp, stats(None), run.spec.trust_run)}, None
    venvs = make_team_vecs(exp, ref, exp.n_envs, run.seed, run_dir, run.vec_env)
    joint = next(iter(venvs.values())).unwrapped.joint  # type: ignore[attr-defined]
    return {g: normalize_for_training(v, exp, stats(g), run.spec.trust_run) for g, v in venvs.items()}, joint


def _callbacks(contexts: Sequence[RunContext], run: _RunPlan, reporter: ProgressReporter) -> list[list[BaseCallback]]:
    """sbagents' own callbacks of each model: progress and periodic evaluation (``best_model.zip``,
    ``evaluations.npz``; for one model per group, of the whole team) on the first model, then each model's
    checkpoints, its kind's callbacks and the config's callbacks."""
    lead = contexts[0]
    scale = lead.timestep_scale
    first: list[BaseCallback] = [ProgressCallback(reporter, scale)]
    first += periodic_evaluation(run.ref.kind, contexts, run.evaluation.n_eval_envs,
                                 EvalReportCallback(reporter, scale), run.vec_env)
    each = []
    for ctx in contexts:
        own = first if ctx is lead else []
        if run.output.save_freq > 0:
            own.append(AtomicCheckpointCallback(ctx.calls(run.output.save_freq), str(ctx.run_dir),
                                                name_prefix=ctx.file_name(CHECKPOINT_PREFIX), save_vecnormalize=True))
        own += model_callbacks(run.ref.kind, ctx)
        own += [cb(**kw) for cb, kw in run.exp.callbacks]
        each.append(own)
    return each


def _build(run: _RunPlan) -> _BuiltRun:
    """Create the run dir (removed again if anything here fails), then for each model (one, or one per group) its
    training env, the model, its context and callbacks; every extension's model hooks run for each model."""
    exp, ref, seed = run.exp, run.ref, run.seed
    with new_run_dir(run.output.log_folder, run.spec.algo, ref.env_id, exp.hyperparams, run.args,
                     run.command) as run_dir:
        set_random_seed(seed)
        envs, joint = _train_envs(run, run_dir)
        # one call of a group's callbacks is one step of the whole team: its agents' steps in all groups
        steps_per_call = exp.n_envs * run.n_agents if joint is not None else None
        contexts = []
        for group, train_env in envs.items():
            for wrap in (a.contribution.wrap_env for a in run.actives if a.contribution.wrap_env is not None):
                train_env = wrap(train_env)
            model = make_model(exp, train_env, seed, run.execution.device,
                               tensorboard_log=run.output.tensorboard_log, verbose=max(run.execution.verbose - 1, 0),
                               resume=run.resumes.get(group), extensions=run.actives)
            contexts.append(RunContext(exp, ref, run_dir, train_env, model, seed, run.eval_freq,
                                       run.evaluation.eval_episodes, trained_agent=_resumed(run, group),
                                       trust_run=run.spec.trust_run, save_freq=run.output.save_freq, group=group,
                                       steps_per_call=steps_per_call))
        # the extensions' callbacks first: what they print comes before the progress bar
        extension_callbacks = [[cb for active in run.actives for cb in active.extension.callbacks(active.spec, ctx)]
                               for ctx in contexts]
        lead = contexts[0]
        steps_before = sum(ctx.model.num_timesteps for ctx in contexts) if run.resumes else 0  # the run's timesteps
        reporter = ProgressReporter(exp.n_timesteps, bar=run.execution.progress, quiet=run.execution.verbose <= 0,
                                    start=steps_before)
        own = _callbacks(contexts, run, reporter)
        models = [_Model(ctx, own[i], extension_callbacks[i]) for i, ctx in enumerate(contexts)]
    env_steps = math.ceil(exp.n_timesteps / steps_per_call) if steps_per_call else 0
    warnings = budget_warnings(lead.model, run.spec.algo, round(exp.n_timesteps / lead.timestep_scale),
                               round(steps_before / lead.timestep_scale))
    for warning in warnings:
        reporter.warn(warning)
    return _BuiltRun(models, reporter, steps_before, warnings, joint, env_steps)


def _learn(run: _RunPlan, built: _BuiltRun, callbacks: Sequence[BaseCallback]) -> LearningClock:
    """Learn inside a graceful clock (the first Ctrl-C / SIGTERM stops every model between two steps): the one
    model's ``learn``, or every group's model in lockstep on one team; the models and the extensions' files are
    saved however it ends. ``callbacks`` (the caller's) run in the first model."""
    lead = built.models[0].ctx.model
    log_interval = run.sb3.log_interval
    if log_interval < 0:
        log_interval = 1 if hasattr(lead, "n_steps") else 100
    clock = LearningClock(graceful=True)
    each = [[StopOnRequestCallback(clock), *m.own, *m.extension_callbacks, *(callbacks if i == 0 else ())]
            for i, m in enumerate(built.models)]
    try:
        with clock:
            if built.joint is None:
                lead.learn(run.exp.n_timesteps, callback=each[0], reset_num_timesteps=not run.resumes,
                           log_interval=log_interval)
            else:
                groups = [str(m.ctx.group) for m in built.models]
                learn_in_lockstep(built.joint, {g: m.ctx.model for g, m in zip(groups, built.models, strict=True)},
                                  built.env_steps, dict(zip(groups, each, strict=True)), log_interval,
                                  reset_num_timesteps=not run.resumes)
    finally:
        built.reporter.close()
        for m in built.models:  # every model saved before any extension's finish
            _save(m.ctx)
        for m in built.models:
            m.items = [active.extension.finish(active.spec, m.ctx) for active in run.actives]
    return clock


def _model_summary(model: _Model) -> dict[str, Any]:
    """One model's ``summary.json`` items: its extensions' and its callbacks' (e.g. a game's learner's illegal moves
    in training: :class:`~sbagents.core.lifecycle.SummaryItems`)."""
    items: dict[str, Any] = {}
    for part in model.items:
        items.update(part)
    for callback in [*model.own, *model.extension_callbacks]:
        if isinstance(callback, SummaryItems):
            items.update(callback.summary_items())
    return items


def _finish(run: _RunPlan, built: _BuiltRun, clock: LearningClock) -> TrainResult:
    """``summary.json`` (each model's extension items: at the top for one model, under ``by_group`` per group's
    model), the final evaluation (of the whole team for one model per group) judged by every extension for each
    model, and the run's result."""
    exp, ref, run_dir = run.exp, run.ref, built.models[0].ctx.run_dir
    steps = sum(m.ctx.model.num_timesteps for m in built.models)
    summary = base_summary(run.spec.algo, ref.env_id, run.seed, steps, steps - built.steps_before, clock)
    if built.warnings:
        summary["warnings"] = built.warnings
    if built.joint is not None:
        summary["groups"] = run.groups
    items = [_model_summary(m) for m in built.models]
    groups = [str(m.ctx.group) for m in built.models]

    def place_by_group() -> None:  # each group's items, where it has any
        by_group = {g: part for g, part in zip(groups, items, strict=True) if part}
        if by_group:
            summary["by_group"] = by_group

    if built.joint is None:
        summary.update(items[0])
        items = [summary]  # the one model's extensions judge the run's summary itself
    else:
        place_by_group()
    options = EvaluateOptions(n_episodes=run.evaluation.final_eval_episodes, seed=run.seed)

    def final_eval() -> dict[str, Any]:
        if built.joint is None:
            result = evaluate_model(built.models[0].ctx.model, exp, ref, options, run_dir / VECNORMALIZE_FILE)
        else:
            result = evaluate_groups({g: m.ctx.model for g, m in zip(groups, built.models, strict=True)}, exp, ref,
                                     options, {g: run_dir / group_stats_name(g) for g in groups})
        for part in items:
            for active in run.actives:
                active.extension.judge(active.spec, part, result)
        if built.joint is not None:
            place_by_group()  # a group whose items were empty may have some now
        return result

    finish_run(run_dir, summary, final_eval if options.n_episodes > 0 else None)
    results: dict[str, Any] = {}
    for m in built.models:
        found = {key: value for part in m.items for key, value in part.items()}
        if built.joint is None:
            results.update(found)
        else:
            results.setdefault("by_group", {})[m.ctx.group] = found
    if built.joint is None:
        return TrainResult(run_dir, built.models[0].ctx.model, exp, summary, clock.interrupted, results)
    return TrainResult(run_dir, None, exp, summary, clock.interrupted, results,
                       models={str(m.ctx.group): m.ctx.model for m in built.models})


def _save(ctx: RunContext) -> None:
    """The VecNormalize statistics, then the model into the run dir (each atomically: a model file that exists is
    complete and has its statistics beside it; ``<EnvStem>.zip`` and ``vecnormalize.npz`` for the run's one model,
    ``<EnvStem>.<group>.zip`` and ``vecnormalize.<group>.npz`` for a group's); the training env is closed."""
    group = ctx.group or SHARED_GROUP
    if isinstance(ctx.train_env, VecNormalize):
        save_vecnormalize(ctx.train_env, ctx.run_dir / group_stats_name(group))
    save_model(ctx.model, ctx.run_dir / group_model_name(env_stem(ctx.ref.env_id), group))
    with contextlib.suppress(EOFError, BrokenPipeError, ConnectionResetError):
        ctx.train_env.close()  # SubprocVecEnv workers may already be gone after Ctrl-C
