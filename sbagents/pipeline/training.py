"""Training with SB3: :func:`train_sb3`, the SB3 backend of ``python -m sbagents.train``.

Flow (docs/architecture.md): :class:`TrainSpec` + zoo config -> :class:`Experiment` -> env factory -> SB3 model +
callbacks -> run directory. Every run checks what it can before the run dir is created (a run of one model per group
builds one team copy to check its groups' spaces); a setup failure removes the half-made run dir; an interrupted run
(Ctrl-C, SIGTERM) still saves its model and logs.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import VecNormalize

from sbagents.atari.envpool_support import training_vec_env
from sbagents.atomic import save_model
from sbagents.callbacks.run_files import AtomicCheckpointCallback
from sbagents.core.env_names import EnvRef, resolve_env
from sbagents.core.experiment import Experiment, build_experiment
from sbagents.core.lifecycle import (
    LearningClock,
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
    best_stats_path,
    check_model_file,
    checkpoint_stats_path,
    env_stem,
    group_stats_name,
)
from sbagents.env_construction import check_env_kwargs
from sbagents.env_factory import make_vec, normalize_for_training
from sbagents.errors import UsageError
from sbagents.extensions import ActiveExtension, ExtensionPlan, activate, registered_extensions
from sbagents.multiagent.groups import team_groups
from sbagents.multiagent.masking import ActedMaskCallback
from sbagents.pipeline.budget import budget_warnings
from sbagents.pipeline.console import EvalReportCallback, ProgressCallback
from sbagents.pipeline.evaluation import evaluate_model
from sbagents.pipeline.kinds import periodic_evaluation, training_env_kwargs
from sbagents.pipeline.models import Resume, RunContext, check_spaces, make_model
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


def _callbacks(ctx: RunContext, n_eval_envs: int, save_freq: int, reporter: ProgressReporter,
               vec_env: str = "auto") -> list[BaseCallback]:
    """Progress, periodic evaluation (``best_model.zip``, ``evaluations.npz``; its env of kind ``vec_env`` where
    that is ``envpool``), checkpoints, config callbacks."""
    exp, ref, run_dir = ctx.exp, ctx.ref, ctx.run_dir
    callbacks: list[BaseCallback] = [ProgressCallback(reporter)]
    callbacks += periodic_evaluation(ref.kind, ctx, n_eval_envs, EvalReportCallback(reporter), vec_env)
    if save_freq > 0:
        callbacks.append(AtomicCheckpointCallback(ctx.calls(save_freq), str(run_dir), name_prefix=CHECKPOINT_PREFIX,
                                                  save_vecnormalize=True))
    callbacks.extend(cb(**kw) for cb, kw in exp.callbacks)
    return callbacks


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

    A fixed sequence: :func:`_plan` (every check, before a run dir exists), then for one model :func:`_build`
    (run dir, envs, model, callbacks), :func:`_learn` and :func:`_finish` (summary, final evaluation); the training
    extensions take part through their hooks at each step.

    :param callbacks: extra SB3 callbacks, after sbagents' own.
    :param features: the specs of the training extensions this run uses (:mod:`sbagents.extensions`: e.g.
        ``TrustOptions``, ``PrivacyOptions``, a ``RobustSpec``), each checked by its extension.
    :param sb3: the vec env and the log interval.
    :return: the run dir, the model and the summary; ``interrupted`` is True after Ctrl-C/SIGTERM.
    """
    run = _plan(spec, output or OutputOptions(), evaluation or EvalOptions(), execution or ExecOptions(),
                sb3 or Sb3Options(), features)
    if run.groups is not None and len(run.groups) > 1:
        return _train_groups(spec, run.exp, run.ref, run.args, run.command,
                             (run.output, run.evaluation, run.execution, run.sb3), run.actives, callbacks)
    built = _build(run)
    clock = _learn(run, built, callbacks)
    return _finish(run, built, clock)


@dataclass
class _RunPlan:
    """A checked run, before its run dir exists: the options, the env, the experiment, the run's extensions (after
    :meth:`~sbagents.extensions.TrainingExtension.prepare`), and what ``args.yml`` records."""

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
    resume: Resume | None
    args: dict[str, Any]
    command: str


def _plan(spec: TrainSpec, output: OutputOptions, evaluation: EvalOptions, execution: ExecOptions,
          sb3: Sb3Options, features: Sequence[Any]) -> _RunPlan:
    """Check everything that can be checked before a run dir exists (one-line :class:`UsageError` otherwise)."""
    for group in (spec, evaluation, execution, sb3):
        group.validate()
    actives = activate(features)
    for active in actives:
        active.extension.validate(active.spec)
    if execution.num_threads > 0:
        torch.set_num_threads(execution.num_threads)
    ref = resolve_env(spec.env, spec.gym_packages)
    exp = build_experiment(spec, ref, tuple(a.extension.overrides_key for a in actives if a.extension.overrides_key))
    if exp.n_timesteps == 0:
        raise UsageError(f"no n_timesteps for {spec.algo} on {ref.env_id} in its config; pass -n N")
    groups = team_agents(exp, ref) if exp.team is not None else None
    plan = ExtensionPlan(spec.algo, exp, ref, team=groups is not None, resuming=spec.trained_agent is not None,
                         n_models=1 if groups is None else len(groups), specs={a.name: a.spec for a in actives},
                         hyperparams=spec.hyperparams)
    actives = _prepare(plan)
    exp = plan.exp
    if groups is not None and len(groups) > 1:
        if spec.trained_agent is not None:
            raise UsageError("-i/--trained-agent continues a single model; this experiment trains one per group")
        refused = [a.extension.flags for a in actives if not a.extension.group_runs]
        if refused:
            raise UsageError(f"{', '.join(refused)} not supported for runs of one model per group ({ref.env_id})")
    if groups is None or len(groups) == 1:
        check_spaces(exp, ref)
    else:
        _check_group_spaces(exp, ref)
    agent_path = check_model_file(spec.trained_agent) if spec.trained_agent is not None else None
    seed = draw_seed(execution.seed)
    vec_env = training_vec_env(sb3.vec_env, exp, ref)  # auto: EnvPool for Atari ids when installed
    eval_freq = evaluation.frequency(exp.n_timesteps)
    args = {"algo": spec.algo, "env": ref.env_id, "seed": seed, "n_timesteps": exp.n_timesteps,
            "log_folder": str(output.log_folder), "eval_freq": eval_freq,
            "eval_episodes": evaluation.eval_episodes, "vec_env": vec_env, "device": execution.device,
            "trained_agent": str(agent_path) if agent_path else None}
    for active in actives:
        args.update(active.extension.record(active.spec))
    if groups is not None:  # the team's agents per step: plots convert team steps to timesteps with it
        args.update(groups=groups, timesteps_per_env_step=sum(len(a) for a in groups.values()))
    return _RunPlan(spec, output, evaluation, execution, sb3, ref, exp, groups, actives, seed, eval_freq, vec_env,
                    Resume(agent_path, spec.trust_run) if agent_path is not None else None, args,
                    output.command or default_command(spec, execution, actives))


@dataclass
class _BuiltRun:
    """An SB3 run ready to learn: its context (run dir, envs, model), reporter and callbacks."""

    ctx: RunContext
    reporter: ProgressReporter
    steps_before: int
    own: list[BaseCallback]
    per_extension: list[list[BaseCallback]]
    warnings: list[str]

    @property
    def extension_callbacks(self) -> list[BaseCallback]:
        """The extensions' callbacks, in extension order."""
        return [cb for cbs in self.per_extension for cb in cbs]


def _resume_stats(model: Path) -> Path:
    """The VecNormalize statistics saved with the model ``-i`` continues: a checkpoint's own
    (``rl_model_vecnormalize_<N>_steps.npz``), ``best_model.zip``'s (``vecnormalize_best.npz``), else the run dir's
    (those of its final model)."""
    steps = checkpoint_steps(model)
    if steps is not None:
        return checkpoint_stats_path(model.parent, steps)
    return best_stats_path(model.parent) if model.name == BEST_MODEL_FILE else model.parent / VECNORMALIZE_FILE


def _build(run: _RunPlan) -> _BuiltRun:
    """Create the run dir (removed again if anything here fails), the training envs, the model and the callbacks."""
    exp, ref, seed, resume = run.exp, run.ref, run.seed, run.resume
    with new_run_dir(run.output.log_folder, run.spec.algo, ref.env_id, exp.hyperparams, run.args,
                     run.command) as run_dir:
        set_random_seed(seed)
        stats = _resume_stats(resume.path) if resume is not None else None
        venv = make_vec(exp, ref, exp.n_envs, seed, run_dir, run.vec_env,
                        env_kwargs=training_env_kwargs(ref.kind, exp, ref, run_dir))
        train_env = normalize_for_training(venv, exp, stats, run.spec.trust_run)
        for active in run.actives:
            train_env = active.extension.wrap_train_env(active.spec, train_env)
        model = make_model(exp, train_env, seed, run.execution.device, tensorboard_log=run.output.tensorboard_log,
                           verbose=max(run.execution.verbose - 1, 0), resume=resume, extensions=run.actives)
        ctx = RunContext(exp, ref, run_dir, train_env, model, seed, run.eval_freq, run.evaluation.eval_episodes,
                         trained_agent=resume.path if resume else None, trust_run=run.spec.trust_run,
                         save_freq=run.output.save_freq)
        for active in run.actives:
            active.extension.setup(active.spec, ctx)
        steps_before = model.num_timesteps if resume is not None else 0
        reporter = ProgressReporter(exp.n_timesteps, bar=run.execution.progress, quiet=run.execution.verbose <= 0,
                                    start=steps_before)
        own = _callbacks(ctx, run.evaluation.n_eval_envs, run.output.save_freq, reporter, run.vec_env)
        if exp.team is not None and isinstance(model, OnPolicyAlgorithm):
            own.append(ActedMaskCallback())  # absent agents' transitions stay out of the rollout's minibatches
        per_extension = [active.extension.callbacks(active.spec, ctx) for active in run.actives]
    warnings = budget_warnings(model, run.spec.algo, exp.n_timesteps, steps_before)
    for warning in warnings:
        reporter.warn(warning)
    return _BuiltRun(ctx, reporter, steps_before, own, per_extension, warnings)


def _learn(run: _RunPlan, built: _BuiltRun, callbacks: Sequence[BaseCallback]) -> LearningClock:
    """``model.learn`` inside a graceful clock; the model and the extensions' files are saved however it ends."""
    model, ctx = built.ctx.model, built.ctx
    log_interval = run.sb3.log_interval
    if log_interval < 0:
        log_interval = 1 if hasattr(model, "n_steps") else 100
    clock = LearningClock(graceful=True)
    try:
        with clock:
            model.learn(run.exp.n_timesteps, callback=[StopOnRequestCallback(clock), *built.own,
                                                       *built.extension_callbacks, *callbacks],
                        reset_num_timesteps=run.resume is None, log_interval=log_interval)
    finally:
        built.reporter.close()
        _save(model, ctx)
        for active in run.actives:
            active.extension.after_learn(active.spec, ctx)
    return clock


def _finish(run: _RunPlan, built: _BuiltRun, clock: LearningClock) -> TrainResult:
    """``summary.json`` (with the extensions' keys and the final evaluation) and the run's result."""
    ctx, model, exp, ref = built.ctx, built.ctx.model, run.exp, run.ref
    summary = base_summary(run.spec.algo, ref.env_id, run.seed, model.num_timesteps,
                           model.num_timesteps - built.steps_before, clock)
    if built.warnings:
        summary["warnings"] = built.warnings
    for active in run.actives:
        summary.update(active.extension.summary(active.spec, ctx))
    for callback in [*built.own, *built.extension_callbacks]:  # e.g. a game's learner's illegal moves in training
        summary.update(getattr(callback, "summary_items", dict)())
    episodes = run.evaluation.final_eval_episodes

    def final_eval() -> dict[str, Any]:
        result = evaluate_model(model, exp, ref, EvaluateOptions(n_episodes=episodes, seed=run.seed),
                                ctx.run_dir / VECNORMALIZE_FILE)
        for active in run.actives:
            active.extension.judge_evaluation(active.spec, summary, result)
        return result

    finish_run(ctx.run_dir, summary, final_eval if episodes > 0 else None)
    results: dict[str, Any] = {}
    for active, cbs in zip(run.actives, built.per_extension, strict=True):
        results.update(active.extension.results(active.spec, cbs))
    return TrainResult(ctx.run_dir, model, exp, summary, clock.interrupted, results)


def _prepare(plan: ExtensionPlan) -> list[ActiveExtension]:
    """Let every registered extension check the plan: :meth:`~sbagents.extensions.TrainingExtension.prepare` for
    those the run uses (in order; each may adjust the experiment and replace a later one's spec),
    :meth:`~sbagents.extensions.TrainingExtension.check_unused` for the others; the run's extensions."""
    for extension in registered_extensions():
        spec = plan.specs.get(extension.name)
        if spec is None:
            extension.check_unused(plan)
            continue
        spec = extension.prepare(spec, plan)
        plan.replace(extension.name, spec)
        plan.exp = extension.adjust_experiment(spec, plan.exp)
    return activate(list(plan.specs.values()))


def team_agents(exp: Experiment, ref: EnvRef) -> dict[str, list[str]]:
    """The groups of a PettingZoo experiment (group -> agents), read from one env built with its kwargs."""
    assert exp.team is not None
    check_env_kwargs(ref, exp.env_kwargs)
    try:
        probe = ref.parallel_env(**exp.env_kwargs)
    except (TypeError, ValueError, AssertionError) as exc:
        given = ", ".join(f"{k}={v!r}" for k, v in exp.env_kwargs.items())
        raise UsageError(f"cannot create {ref.env_id} with env kwargs {given}: {exc}") from None
    agents = [str(a) for a in probe.possible_agents]
    probe.close()
    return team_groups(exp.team, agents)


def _check_group_spaces(exp: Experiment, ref: EnvRef) -> None:
    """Refuse, before a run dir exists, a group whose spaces the algorithm cannot act in (one team copy is built
    and closed)."""
    from sbagents.env_factory import make_team_vecs
    from sbagents.pipeline.team_training import check_group_spaces

    venvs = make_team_vecs(exp, ref, 1, None, vec_env="dummy")
    try:
        check_group_spaces(exp, venvs)
    finally:
        next(iter(venvs.values())).close()


def _train_groups(
    spec: TrainSpec, exp: Experiment, ref: EnvRef, args: dict[str, Any], command: str,
    options: tuple[OutputOptions, EvalOptions, ExecOptions, Sb3Options], actives: Sequence[ActiveExtension],
    callbacks: Sequence[BaseCallback],
) -> TrainResult:
    """The run of one model per group (:mod:`sbagents.pipeline.team_training`): every extension's model hooks run
    once per group's model (``summary.json`` keeps their items per group under ``by_group``); extensions that
    cannot serve such runs were refused in :func:`_plan`."""
    from sbagents.pipeline.evaluation import evaluate_groups
    from sbagents.pipeline.team_training import build_groups, learn_groups

    output, evaluation, _, sb3 = options
    seed = int(args["seed"])
    with new_run_dir(output.log_folder, spec.algo, ref.env_id, exp.hyperparams, args, command) as run_dir:
        set_random_seed(seed)
        setup = build_groups(exp, ref, run_dir, seed, options, actives, callbacks)
    clock = LearningClock()
    learn_groups(setup, clock, sb3.log_interval, run_dir, env_stem(ref.env_id), actives)
    steps = sum(m.num_timesteps for m in setup.models.values())
    summary = {**base_summary(spec.algo, ref.env_id, seed, steps, steps, clock), "groups": setup.groups}
    by_group: dict[str, dict[str, Any]] = {}
    results: dict[str, Any] = {}
    for group, ctx in setup.contexts.items():
        items: dict[str, Any] = {}
        for active, cbs in zip(actives, setup.extension_callbacks[group], strict=True):
            items.update(active.extension.summary(active.spec, ctx))
            results.setdefault("by_group", {}).setdefault(group, {}).update(active.extension.results(active.spec,
                                                                                                      cbs))
        if items:
            by_group[group] = items
    if by_group:
        summary["by_group"] = by_group

    def final_eval() -> dict[str, Any]:
        stats = {g: run_dir / group_stats_name(g) for g in setup.groups}
        return evaluate_groups(setup.models, exp, ref,
                               EvaluateOptions(n_episodes=evaluation.final_eval_episodes, seed=seed), stats)

    finish_run(run_dir, summary, final_eval if evaluation.final_eval_episodes > 0 else None)
    return TrainResult(run_dir, None, exp, summary, clock.interrupted, results, models=setup.models)


def _save(model: BaseAlgorithm, ctx: RunContext) -> None:
    """The VecNormalize statistics, then the final model into the run dir (each atomically: a model file that
    exists is complete and has its statistics beside it); the training env is closed."""
    if isinstance(ctx.train_env, VecNormalize):
        save_vecnormalize(ctx.train_env, ctx.run_dir / VECNORMALIZE_FILE)
    save_model(model, ctx.run_dir / f"{env_stem(ctx.ref.env_id)}.zip")
    with contextlib.suppress(EOFError, BrokenPipeError, ConnectionResetError):
        ctx.train_env.close()  # SubprocVecEnv workers may already be gone after Ctrl-C
