"""``--dp-*``: DP-SGD training (:mod:`sbagents.private`) as a training extension (:mod:`sbagents.extensions`).

Opacus is imported only when a run asks for DP training (the ``private`` extra).
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

from sbagents.capabilities import Capability
from sbagents.core.extensions import Contribution, ExtensionPlan, SpecRecord, TrainingContext, TrainingExtension
from sbagents.errors import UsageError
from sbagents.private.options import DP_ALGOS, DP_TRAINING, PrivacyOptions


class PrivacyExtension(TrainingExtension[PrivacyOptions]):
    """``--dp-epsilon`` / ``--dp-noise`` (+ ``--dp-delta``, ``--dp-clip``): Poisson-sampled batches, per-transition
    clipping and noise (Opacus), frozen observation statistics, the entry's ``dp_overrides``; ``summary.json``'s
    ``dp`` item and its console line."""

    name = "privacy"
    title = "privacy (DP-SGD with Opacus; ddpg, td3, sac, ppo, a2c; pip install 'sbagents[private]')"
    flags = "--dp-*"
    spec_type = PrivacyOptions
    group_runs = False  # DP-SGD accounts for one model's data
    overrides_key = "dp_overrides"
    algos = DP_ALGOS
    kinds = DP_TRAINING.kinds

    def add_arguments(self, group: argparse._ArgumentGroup) -> None:
        group.add_argument("--dp-epsilon", type=float, default=None, metavar="E",
                           help="train with (E, delta)-DP per transition: noise calibrated to the run's draws (ppo, "
                                "a2c: to one rollout's; with --dp-noise: stop before passing E)")
        group.add_argument("--dp-delta", type=float, default=None, metavar="D",
                           help="delta, below 1 / the transitions trained on (default 1e-5)")
        group.add_argument("--dp-clip", type=float, default=None, metavar="C",
                           help="per-transition gradient clipping norm (default 1.0)")
        group.add_argument("--dp-noise", type=float, default=None, metavar="SIGMA",
                           help="noise multiplier instead of a calibrated one (epsilon is reported)")

    def from_args(self, args: argparse.Namespace) -> PrivacyOptions | None:
        """The ``--dp-*`` flags; ``--dp-delta`` / ``--dp-clip`` alone are refused (they would do nothing)."""
        if args.dp_epsilon is None and args.dp_noise is None:
            if args.dp_delta is not None or args.dp_clip is not None:
                raise UsageError("--dp-delta and --dp-clip apply to DP training: add --dp-epsilon E or --dp-noise "
                                 "SIGMA")
            return None
        defaults = PrivacyOptions()
        return PrivacyOptions(epsilon=args.dp_epsilon, noise=args.dp_noise,
                              delta=defaults.delta if args.dp_delta is None else args.dp_delta,
                              clip=defaults.clip if args.dp_clip is None else args.dp_clip)

    def is_active(self, spec: PrivacyOptions) -> bool:
        return spec.enabled

    def capabilities(self) -> list[Capability]:
        return [DP_TRAINING]

    def configure(self, spec: PrivacyOptions | None, plan: ExtensionPlan) -> PrivacyOptions | None:
        if spec is None:
            return None
        try:
            from sbagents.private.training import check_dp_experiment, private_experiment
        except ImportError as exc:
            raise UsageError(f"DP training needs Opacus: pip install 'sbagents[private]' ({exc})") from None
        check_dp_experiment(spec, plan.exp, plan.resuming)
        plan.exp = private_experiment(plan.exp)
        return spec

    def contribute(self, spec: PrivacyOptions, plan: ExtensionPlan) -> Contribution:
        from sbagents.private.training import freeze_normalization

        return Contribution(wrap_env=freeze_normalization)

    def record(self, spec: PrivacyOptions) -> SpecRecord:
        defaults = PrivacyOptions()
        given = {"--dp-epsilon": spec.epsilon, "--dp-noise": spec.noise,
                 "--dp-delta": None if spec.delta == defaults.delta else spec.delta,
                 "--dp-clip": None if spec.clip == defaults.clip else spec.clip}
        return SpecRecord(flags=[arg for flag, value in given.items() if value is not None
                                 for arg in (flag, str(value))])

    def callbacks(self, spec: PrivacyOptions, ctx: TrainingContext) -> list[BaseCallback]:
        from sbagents.private.training import make_dp_callback

        return [make_dp_callback(ctx.model, spec, ctx.exp.n_timesteps)]

    def describe(self, summary: Mapping[str, Any], run_dir: Path) -> list[str]:
        dp = summary.get("dp")
        if not dp:
            return []
        stop = "; stopped at the budget" if dp.get("stopped_at_budget") else ""
        rollout = ""
        if dp.get("composition"):  # on-policy: the exposure of one transition is its own rollout's steps
            all_steps = dp.get("epsilon_all_steps")
            rollout = "; per rollout" + ("" if all_steps is None else f", {all_steps:.2f} over all steps composed")
        unit = dp.get("unit", "transition")
        return [f"privacy: epsilon {dp['epsilon']:.2f} at delta {dp['delta']:g} per {unit} (noise "
                f"{dp['noise_multiplier']:.3g}, clip {dp['max_grad_norm']:g}; RDP accountant, Poisson "
                f"batches{rollout}){stop}"]


__all__ = ["PrivacyExtension"]
