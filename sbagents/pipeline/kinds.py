"""What each env kind (:mod:`sbagents.core.env_kinds`) means for an SB3 training run: the groups of models it trains,
its periodic evaluation, the callbacks each model gets and the extra keyword arguments of its training envs, each a
:func:`~sbagents.core.env_kinds.kind_operation`."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

from sbagents.callbacks.run_files import AtomicEvalCallback
from sbagents.core.env_kinds import EnvKind, GameKind, TeamKind, kind_operation
from sbagents.core.env_names import EnvRef
from sbagents.core.experiment import Experiment
from sbagents.core.team_options import TeamOptions
from sbagents.env_construction import check_env_kwargs
from sbagents.env_factory import make_eval_vec, make_team_vecs, normalize_for_eval
from sbagents.errors import UsageError
from sbagents.pipeline.models import RunContext

#: Seed offsets of the evaluation envs (distinct from the training envs' seeds).
EVAL_SEED_OFFSET = 10_000


@kind_operation(GameKind)
def model_groups(kind: EnvKind, exp: Experiment, ref: EnvRef) -> dict[str, list[str]] | None:
    """The groups of agents a run trains one model each for (group -> agents; one group ``shared`` for a shared
    policy), or None: the env has one learner (a Gymnasium env; a game's learning seat)."""
    return None


@model_groups.register
def _team_model_groups(kind: TeamKind, exp: Experiment, ref: EnvRef) -> dict[str, list[str]] | None:
    """A team: its groups, read from one env built with the experiment's kwargs."""
    from sbagents.multiagent.competition import zero_sum_under_random_play
    from sbagents.multiagent.groups import team_groups

    check_env_kwargs(ref, exp.env_kwargs)
    try:
        probe = ref.parallel_env(**exp.env_kwargs)
    except (TypeError, ValueError, AssertionError) as exc:
        given = ", ".join(f"{k}={v!r}" for k, v in exp.env_kwargs.items())
        raise UsageError(f"cannot create {ref.env_id} with env kwargs {given}: {exc}") from None
    agents = [str(a) for a in probe.possible_agents]
    groups = team_groups(TeamOptions.of(exp), agents)
    try:
        if len(groups) == 1 and zero_sum_under_random_play(probe):  # one shared policy plays every side
            print(f"warning: {ref.env_id}'s agents compete (their rewards sum to 0 at every step under random play): "
                  "one shared policy plays every side and the team return is 0 by construction; train one model "
                  "per side with -params policies:per_agent", file=sys.stderr, flush=True)
    finally:
        probe.close()
    return groups


@kind_operation(GameKind)
def model_callbacks(kind: EnvKind, ctx: RunContext) -> list[BaseCallback]:
    """Callbacks the kind adds to each model of a run (none for most kinds)."""
    return []


@model_callbacks.register
def _team_model_callbacks(kind: TeamKind, ctx: RunContext) -> list[BaseCallback]:
    """A team, on-policy: absent agents' transitions stay out of the rollout's minibatches."""
    from sbagents.multiagent.masking import ActedMaskCallback

    return [ActedMaskCallback()] if isinstance(ctx.model, OnPolicyAlgorithm) else []


@kind_operation()
def periodic_evaluation(kind: EnvKind, contexts: Sequence[RunContext], n_eval_envs: int, after_eval: BaseCallback,
                        vec_env: str = "auto") -> list[BaseCallback]:
    """The callbacks (of the first model, ``contexts[0]``) that evaluate a run every ``eval_freq`` env steps
    (``best_model.zip``, ``evaluations.npz``) and call ``after_eval`` after each evaluation; none when
    ``eval_freq <= 0``.

    A Gymnasium env: SB3's EvalCallback (written atomically) on ``n_eval_envs`` envs (EnvPool's when the training
    envs are EnvPool's).
    """
    ctx = contexts[0]
    if ctx.eval_freq <= 0:
        return []
    eval_env = make_eval_vec(ctx.exp, ctx.ref, n_eval_envs, ctx.seed + EVAL_SEED_OFFSET,
                             vec_env="envpool" if vec_env == "envpool" else "auto")
    return [AtomicEvalCallback(eval_env, deterministic=ctx.exp.deterministic_eval, **_eval_settings(ctx, after_eval))]


@periodic_evaluation.register
def _team_periodic_evaluation(kind: TeamKind, contexts: Sequence[RunContext], n_eval_envs: int,
                              after_eval: BaseCallback, vec_env: str = "auto") -> list[BaseCallback]:
    """A team: whole-team episodes on one env (team return, per-agent returns), every group's model acting; the best
    team's models are kept (``best_model.zip``, or ``best_model.<group>.zip`` per group)."""
    ctx = contexts[0]
    if ctx.eval_freq <= 0:
        return []
    from sbagents.multiagent.team_eval import TeamEvalCallback

    if ctx.group is None:
        team_env: Any = make_eval_vec(ctx.exp, ctx.ref, 1, None, vec_env="dummy")
        models = None
    else:
        team_env = {g: normalize_for_eval(v, ctx.exp)
                    for g, v in make_team_vecs(ctx.exp, ctx.ref, 1, None, vec_env="dummy").items()}
        models = {str(c.group): c.model for c in contexts}
    return [TeamEvalCallback(team_env, seed=ctx.seed + EVAL_SEED_OFFSET, deterministic=ctx.exp.deterministic_eval,
                             models=models, timestep_scale=ctx.timestep_scale, **_eval_settings(ctx, after_eval))]


@periodic_evaluation.register
def _game_periodic_evaluation(kind: GameKind, contexts: Sequence[RunContext], n_eval_envs: int,
                              after_eval: BaseCallback, vec_env: str = "auto") -> list[BaseCallback]:
    """A turn-based game: matches against the evaluation opponent, snapshots into the self-play pool, Elo."""
    from sbagents.games.training import game_callbacks

    ctx = contexts[0]
    eval_calls = ctx.eval_calls() if ctx.eval_freq > 0 else 0
    return game_callbacks(ctx.exp, ctx.ref, ctx.run_dir, ctx.seed, ctx.train_env.num_envs, eval_calls,
                          ctx.eval_episodes, after_eval, make_eval_env=make_eval_vec)


def _eval_settings(ctx: RunContext, after_eval: BaseCallback) -> dict[str, Any]:
    return dict(n_eval_episodes=ctx.eval_episodes, eval_freq=ctx.eval_calls(), log_path=str(ctx.run_dir),
                best_model_save_path=str(ctx.run_dir), verbose=0, callback_after_eval=after_eval)


@kind_operation(TeamKind)
def training_env_kwargs(kind: EnvKind, exp: Experiment, ref: EnvRef, run_dir: Path) -> dict[str, Any] | None:
    """Extra keyword arguments of the training envs (none for most kinds)."""
    return None


@training_env_kwargs.register
def _game_training_env_kwargs(kind: GameKind, exp: Experiment, ref: EnvRef, run_dir: Path) -> dict[str, Any] | None:
    """A turn-based game: the training envs draw opponents from the run's snapshot pool."""
    from sbagents.games.training import training_env_kwargs

    return training_env_kwargs(exp, ref, run_dir)
