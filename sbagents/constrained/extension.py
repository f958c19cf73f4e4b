"""``--constraint lagrangian|pid``: constrained training (:mod:`sbagents.constrained`) as a training extension
(:mod:`sbagents.extensions`)."""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from stable_baselines3.common.base_class import BaseAlgorithm

from sbagents.capabilities import Capability
from sbagents.constrained.options import (
    CONFIG_KEY,
    CONSTRAINED_ALGOS,
    ConstraintSpec,
    check_unconstrained,
    constrained_class,
    constraint_spec,
    judge_evaluation,
    record_constraint,
)
from sbagents.core.env_kinds import SINGLE_AGENT
from sbagents.core.extensions import (
    TAKEN,
    Contribution,
    ExtensionPlan,
    SpecRecord,
    TrainingContext,
    TrainingExtension,
)


def _verdict(held: bool | None, cost: float | None, where: str, measure: str) -> str:
    if held is None or cost is None:
        return f"not measured {where}"
    return f"{'held' if held else 'missed'} {where} ({measure} {cost:.3g})"


def constraint_line(constraint: Mapping[str, Any]) -> str:
    """``constraint (lagrangian): cost limit 0.5 missed in training (recent episodes' mean cost 0.93); missed in the
    final evaluation (mean episode cost 1); multiplier 2.9``."""
    parts = [_verdict(constraint.get("held_in_training"), constraint.get("train_ep_cost"), "in training",
                      "recent episodes' mean cost")]
    if "held_in_evaluation" in constraint:
        parts.append(_verdict(constraint["held_in_evaluation"], constraint.get("eval_ep_cost"),
                              "in the final evaluation", "mean episode cost"))
    return (f"constraint ({constraint['method']}): cost limit {constraint['cost_limit']:g} {'; '.join(parts)}; "
            f"multiplier {constraint['multiplier']:.3g}")


class ConstraintExtension(TrainingExtension[ConstraintSpec]):
    """``--constraint`` with ``--cost-limit`` (a trust flag) and the entry's ``constraint_kwargs``: the algorithm's
    constrained class (PPO-/SAC-Lagrangian), safety counting without the stop (the multiplier holds the limit), the
    constraint's history in ``safety.json`` and its verdicts in ``summary.json``; a run dir whose ``args.yml`` has a
    constraint loads with the constrained class."""

    name = "constraint"
    title = "constrained training (sbagents.constrained)"
    flags = "--constraint"
    spec_type = ConstraintSpec
    group_runs = False  # the multiplier is one model's
    config_keys = frozenset({CONFIG_KEY})
    algos = CONSTRAINED_ALGOS
    kinds = (SINGLE_AGENT.name,)

    def add_arguments(self, group: argparse._ArgumentGroup) -> None:
        group.add_argument("--constraint", choices=["lagrangian", "pid"], default=None,
                           help="train under --cost-limit: PPO-Lagrangian (ppo) or SAC-Lagrangian (sac) with a cost "
                                "critic and a Lagrange (or PID) multiplier, settings from the entry's "
                                "constraint_kwargs; safety.json records its history")

    def from_args(self, args: argparse.Namespace) -> ConstraintSpec | None:
        return None if args.constraint is None else ConstraintSpec(args.constraint, args.cost_limit)

    def capabilities(self) -> list[Capability]:
        return [Capability("constrained", "--constraint (Lagrangian / PID multiplier)", self.algos, self.kinds,
                           label=self.flags)]

    def requires(self, spec: ConstraintSpec) -> Mapping[str, Mapping[str, Any]]:
        # the multiplier holds the limit: count violations, never stop at it (--cost-limit is the limit trained for)
        return {"trust": {"safety": True, "cost_limit": TAKEN}}

    def configure(self, spec: ConstraintSpec | None, plan: ExtensionPlan) -> ConstraintSpec | None:
        if spec is None:
            check_unconstrained(plan.algo, plan.exp.hyperparams, dict(plan.hyperparams))
            return None
        given = getattr(plan.given.get("trust"), "cost_limit", None)  # a run from Python may give it there
        limit = spec.cost_limit if spec.cost_limit is not None else given
        return constraint_spec(spec.method, plan.algo, limit, plan.exp.hyperparams.get(CONFIG_KEY),
                               f"entry for {plan.exp.env_id}")

    def contribute(self, spec: ConstraintSpec, plan: ExtensionPlan) -> Contribution:
        def load(cls: type, path: Path, **kwargs: Any) -> BaseAlgorithm:
            # the saved multiplier and its state continue (under the new cost limit); the constructor's keywords
            # are not passed again
            for key in spec.model_kwargs():
                kwargs.pop(key, None)
            return spec.load_model(cls, path, **kwargs)

        return Contribution(model_class=spec.model_class(plan.algo), model_kwargs=spec.model_kwargs(), load=load)

    def record(self, spec: ConstraintSpec) -> SpecRecord:
        return SpecRecord(args=spec.record(), flags=["--constraint", spec.method])

    def finish(self, spec: ConstraintSpec, ctx: TrainingContext) -> dict[str, Any]:
        return record_constraint(ctx.run_dir, ctx.model)

    def judge(self, spec: ConstraintSpec, summary: dict[str, Any], evaluation: Mapping[str, Any]) -> None:
        judge_evaluation(summary["constraint"], evaluation)  # did the limit hold for the greedy policy too

    def describe(self, summary: Mapping[str, Any], run_dir: Path) -> list[str]:
        constraint = summary.get("constraint")
        return [constraint_line(constraint)] if constraint else []

    def load_class(self, algo: str, args: Mapping[str, Any]) -> type | None:
        # a constrained run's zip holds a cost critic the plain class refuses
        return constrained_class(algo) if args.get("constraint") else None
