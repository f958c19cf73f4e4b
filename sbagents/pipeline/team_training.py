"""Training one SB3 model per group of a PettingZoo env's agents (``policies: per_agent | per_group``): the SB3
backend's path for such experiments (:func:`train_groups`, called by :func:`sbagents.pipeline.training.train_sb3`).

The models learn side by side on one team (:func:`sbagents.multiagent.lockstep.learn_in_lockstep`), each on its own
rollout or replay data. ``n_timesteps`` counts agent steps of the whole team, as for a shared policy. The run dir
holds one model per group (``<EnvId>.<group>.zip``, ``best_model.<group>.zip``, ``vecnormalize.<group>.npz``) and
the groups in ``args.yml``; evaluation, export and video load them all.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sbagents.algos import ALGOS, algos_for
from sbagents.atomic import save_model
from sbagents.callbacks.run_files import AtomicCheckpointCallback
from sbagents.core.env_names import EnvRef
from sbagents.core.experiment import Experiment
from sbagents.core.lifecycle import LearningClock
from sbagents.core.options import EvalOptions, ExecOptions, OutputOptions, Sb3Options
from sbagents.core.progress import ProgressReporter
from sbagents.core.run_dir import CHECKPOINT_PREFIX, group_model_name, group_stats_name
from sbagents.env_factory import make_team_vecs, normalize_for_eval, normalize_for_training
from sbagents.errors import UsageError
from sbagents.extensions import ActiveExtension
from sbagents.multiagent.lockstep import learn_in_lockstep
from sbagents.multiagent.masking import ActedMaskCallback
from sbagents.multiagent.team_eval import TeamEvalCallback, slot_agents
from sbagents.pipeline.console import EvalReportCallback, ProgressCallback
from sbagents.pipeline.kinds import EVAL_SEED_OFFSET
from sbagents.pipeline.models import RunContext, make_model
from sbagents.state_files import save_vecnormalize


def team_groups_of(venvs: dict[str, VecEnv]) -> dict[str, list[str]]:
    """Group -> its agents, from the group VecEnvs."""
    return {g: slot_agents(v, g) for g, v in venvs.items()}


def check_group_spaces(exp: Experiment, venvs: dict[str, VecEnv]) -> None:
    """Raise :class:`UsageError` naming the group whose spaces the algorithm cannot act in."""
    for group, venv in venvs.items():
        if not ALGOS[exp.algo].supports(venv.observation_space, venv.action_space):
            able = ", ".join(algos_for(venv.observation_space, venv.action_space)) or "none"
            raise UsageError(f"{exp.algo} cannot learn group {group} of {exp.env_id} (observation "
                             f"{type(venv.observation_space).__name__}, action {type(venv.action_space).__name__}); "
                             f"algos that can: {able}")


def _group_callbacks(
    exp: Experiment, models: dict[str, BaseAlgorithm], run_dir: Path, output: OutputOptions,
    calls_per_env_step: float,
) -> dict[str, list[BaseCallback]]:
    each: dict[str, list[BaseCallback]] = {}
    for group, model in models.items():
        own: list[BaseCallback] = [ActedMaskCallback()] if isinstance(model, OnPolicyAlgorithm) else []
        if output.save_freq > 0:
            own.append(AtomicCheckpointCallback(max(round(output.save_freq * calls_per_env_step), 1), str(run_dir),
                                                name_prefix=f"{CHECKPOINT_PREFIX}.{group}", save_vecnormalize=True))
        own += [cb(**kw) for cb, kw in exp.callbacks]
        each[group] = own
    return each


@dataclass
class GroupSetup:
    """What :func:`build_groups` made: the group VecEnvs and models, their callbacks, the console reporter, the
    team coordinator and the budget in team steps."""

    venvs: dict[str, VecEnv]
    models: dict[str, BaseAlgorithm]
    callbacks: dict[str, list[BaseCallback]]
    reporter: ProgressReporter
    joint: Any
    env_steps: int
    groups: dict[str, list[str]] = field(default_factory=dict)
    #: each group's model's context (what the extensions' hooks see)
    contexts: dict[str, RunContext] = field(default_factory=dict)
    #: each group's callbacks per extension, in extension order
    extension_callbacks: dict[str, list[list[BaseCallback]]] = field(default_factory=dict)


def build_groups(
    exp: Experiment, ref: EnvRef, run_dir: Path, seed: int,
    options: tuple[OutputOptions, EvalOptions, ExecOptions, Sb3Options],
    actives: Sequence[ActiveExtension] = (), callbacks: Sequence[BaseCallback] = (),
) -> GroupSetup:
    """The group models of ``exp`` on one team writing into ``run_dir``, with their callbacks; every extension's
    model hooks (``wrap_train_env``, ``model_class``, ``setup``, ``callbacks``) run once per group's model, with a
    :class:`~sbagents.pipeline.models.RunContext` whose ``group`` names it.

    :param options: the run's output, evaluation, execution and SB3 options.
    :param actives: the run's training extensions.
    :param callbacks: extra SB3 callbacks for every group's model.
    """
    output, evaluation, execution, sb3 = options
    venvs = {g: normalize_for_training(v, exp) for g, v in
             make_team_vecs(exp, ref, exp.n_envs, seed, run_dir, sb3.vec_env).items()}
    for group in venvs:
        for active in actives:
            venvs[group] = active.extension.wrap_train_env(active.spec, venvs[group])
    groups = team_groups_of(venvs)
    check_group_spaces(exp, venvs)
    verbose = max(execution.verbose - 1, 0)
    models = {g: make_model(exp, v, seed, execution.device, tensorboard_log=output.tensorboard_log,
                            verbose=verbose, extensions=actives)
              for g, v in venvs.items()}
    eval_freq = evaluation.frequency(exp.n_timesteps)
    contexts = {g: RunContext(exp, ref, run_dir, venvs[g], models[g], seed, eval_freq, evaluation.eval_episodes,
                              save_freq=output.save_freq, group=g) for g in venvs}
    for ctx in contexts.values():
        for active in actives:
            active.extension.setup(active.spec, ctx)
    per_extension = {g: [active.extension.callbacks(active.spec, ctx) for active in actives]
                     for g, ctx in contexts.items()}
    first = next(iter(groups))
    n_agents = sum(len(a) for a in groups.values())
    slots_per_env_step = exp.n_envs * n_agents  # the run's timesteps per team step, as for a shared policy
    reporter = ProgressReporter(exp.n_timesteps, bar=execution.progress, quiet=execution.verbose <= 0)
    scale = n_agents / len(groups[first])
    head: list[BaseCallback] = [ProgressCallback(reporter, scale)]
    if eval_freq > 0:
        eval_envs = {g: normalize_for_eval(v, exp) for g, v in
                     make_team_vecs(exp, ref, 1, None, vec_env="dummy").items()}
        lead = models[first]
        rollout = lead.n_steps if isinstance(lead, OnPolicyAlgorithm) else 1
        head.append(TeamEvalCallback(eval_envs, evaluation.eval_episodes,
                                     max(eval_freq // slots_per_env_step, rollout),  # at least one rollout
                                     str(run_dir), str(run_dir), exp.deterministic_eval, seed + EVAL_SEED_OFFSET,
                                     models=models,
                                     callback_after_eval=EvalReportCallback(reporter, scale), verbose=0,
                                     timestep_scale=scale))
    each = _group_callbacks(exp, models, run_dir, output, 1 / slots_per_env_step)
    per_group = {g: [*(head if g == first else []), *each[g], *(cb for cbs in per_extension[g] for cb in cbs),
                     *callbacks] for g in groups}
    joint = next(iter(venvs.values())).unwrapped.joint  # type: ignore[attr-defined]
    return GroupSetup(venvs, models, per_group, reporter, joint, math.ceil(exp.n_timesteps / slots_per_env_step),
                      groups, contexts, per_extension)


def learn_groups(setup: GroupSetup, clock: LearningClock, log_interval: int, run_dir: Path, stem: str,
                 actives: Sequence[ActiveExtension] = ()) -> None:
    """Learn the models of ``setup`` in lockstep inside ``clock``; save them (and their statistics) and run every
    extension's ``after_learn`` per group's model in any case."""
    try:
        with clock:
            learn_in_lockstep(setup.joint, setup.models, setup.env_steps, setup.callbacks,
                              log_interval if log_interval > 0 else 1)
    finally:
        setup.reporter.close()
        _save(setup.models, setup.venvs, run_dir, stem)
        for ctx in setup.contexts.values():
            for active in actives:
                active.extension.after_learn(active.spec, ctx)


def _save(models: dict[str, BaseAlgorithm], venvs: dict[str, VecEnv], run_dir: Path, stem: str) -> None:
    for group, model in models.items():  # statistics first: a model file that exists has them beside it
        if isinstance(venvs[group], VecNormalize):
            save_vecnormalize(venvs[group], run_dir / group_stats_name(group))
        save_model(model, run_dir / group_model_name(stem, group))
    for venv in venvs.values():
        with contextlib.suppress(EOFError, BrokenPipeError, ConnectionResetError):
            venv.close()
