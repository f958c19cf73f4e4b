"""``--robust``: robust training (:mod:`sbagents.robust`) as a training extension (:mod:`sbagents.extensions`)."""

from __future__ import annotations

import argparse

from sbagents.capabilities import Capability
from sbagents.core.extensions import Contribution, ExtensionPlan, SpecRecord, TrainingExtension
from sbagents.robust.options import ROBUST_ALGOS, ROBUST_KINDS, ROBUST_METHODS, RobustSpec, parse_robust


class RobustExtension(TrainingExtension[RobustSpec]):
    """``--robust METHOD:EPS[,KEY=VALUE...]``: the algorithm's robust class (SA regularizer, adversarial rollouts),
    the entry's ``robust_overrides`` applied, ``robust`` recorded in ``args.yml``; SB3 single-agent runs only."""

    name = "robust"
    title = "robust training (sbagents.robust)"
    flags = "--robust"
    spec_type = RobustSpec
    group_runs = False  # the adversary attacks one model's observations
    overrides_key = "robust_overrides"
    algos = tuple(dict.fromkeys(algo for algos in ROBUST_ALGOS.values() for algo in algos))  # with some method
    kinds = ROBUST_KINDS

    def add_arguments(self, group: argparse._ArgumentGroup) -> None:
        group.add_argument("--robust", default=None, metavar="SPEC",
                           help="METHOD:EPS[,KEY=VALUE...]: sa (state-adversarial regularizer; ddpg, td3; keys kappa, "
                                "steps, qdrop, ramp), adv (adversarial rollouts; ddpg, td3, sac; keys attack, share, "
                                "ramp) or sa+adv; eps in the attacks' units, ramped up over the first half of training")

    def from_args(self, args: argparse.Namespace) -> RobustSpec | None:
        return None if args.robust is None else parse_robust(args.robust, args.algo)

    def capabilities(self) -> list[Capability]:
        return list(ROBUST_METHODS.values())

    def capability(self, spec: RobustSpec) -> Capability:
        return ROBUST_METHODS[spec.method]

    def contribute(self, spec: RobustSpec, plan: ExtensionPlan) -> Contribution:
        return Contribution(model_class=spec.model_class(plan.algo), model_kwargs=spec.model_kwargs())

    def record(self, spec: RobustSpec) -> SpecRecord:
        return SpecRecord(args={"robust": spec.flag_value()}, flags=["--robust", spec.flag_value()])
