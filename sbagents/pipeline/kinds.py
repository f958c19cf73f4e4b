"""What each env kind (:mod:`sbagents.core.env_kinds`) means for an SB3 training run: its periodic evaluation and the
extra keyword arguments of its training envs, registered per kind with :func:`functools.singledispatch`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

from sbagents.callbacks.run_files import AtomicEvalCallback
from sbagents.core.env_kinds import EnvKind, GameKind, TeamKind, kind_operation
from sbagents.core.env_names import EnvRef
from sbagents.core.experiment import Experiment
from sbagents.env_factory import make_eval_vec
from sbagents.pipeline.models import RunContext

#: Seed offsets of the evaluation envs (distinct from the training envs' seeds).
EVAL_SEED_OFFSET = 10_000


@kind_operation()
def periodic_evaluation(kind: EnvKind, ctx: RunContext, n_eval_envs: int, after_eval: BaseCallback,
                        vec_env: str = "auto") -> list[BaseCallback]:
    """The callbacks that evaluate a run every ``ctx.eval_freq`` env steps (``best_model.zip``, ``evaluations.npz``)
    and call ``after_eval`` after each evaluation; none when ``ctx.eval_freq <= 0``.

    A Gymnasium env: SB3's EvalCallback (written atomically) on ``n_eval_envs`` envs (EnvPool's when the training
    envs are EnvPool's).
    """
    if ctx.eval_freq <= 0:
        return []
    eval_env = make_eval_vec(ctx.exp, ctx.ref, n_eval_envs, ctx.seed + EVAL_SEED_OFFSET,
                             vec_env="envpool" if vec_env == "envpool" else "auto")
    return [AtomicEvalCallback(eval_env, deterministic=ctx.exp.deterministic_eval, **_eval_settings(ctx, after_eval))]


@periodic_evaluation.register
def _(kind: TeamKind, ctx: RunContext, n_eval_envs: int, after_eval: BaseCallback,
      vec_env: str = "auto") -> list[BaseCallback]:
    """A team: whole-team episodes on one env (team return, per-agent returns)."""
    if ctx.eval_freq <= 0:
        return []
    from sbagents.multiagent.team_eval import TeamEvalCallback

    team_env = make_eval_vec(ctx.exp, ctx.ref, 1, None, vec_env="dummy")
    return [TeamEvalCallback(team_env, seed=ctx.seed + EVAL_SEED_OFFSET, deterministic=ctx.exp.deterministic_eval,
                             **_eval_settings(ctx, after_eval))]


@periodic_evaluation.register
def _(kind: GameKind, ctx: RunContext, n_eval_envs: int, after_eval: BaseCallback,
      vec_env: str = "auto") -> list[BaseCallback]:
    """A turn-based game: matches against the evaluation opponent, snapshots into the self-play pool, Elo."""
    from sbagents.games.training import game_callbacks

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
def _(kind: GameKind, exp: Experiment, ref: EnvRef, run_dir: Path) -> dict[str, Any] | None:
    """A turn-based game: the training envs draw opponents from the run's snapshot pool."""
    from sbagents.games.training import training_env_kwargs

    return training_env_kwargs(exp, ref, run_dir)
