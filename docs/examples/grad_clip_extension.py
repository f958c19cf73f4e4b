"""A training extension of your own: ``--grad-clip X`` caps the gradient norm of any algorithm that has one.

Run it with ``python -m sbagents.train --gym-packages grad_clip_extension --algo ppo --grad-clip 0.3`` (this folder
on ``PYTHONPATH``), or from Python: ``register_extension(GradClipExtension())``, then
``train(..., features=[GradClip(0.3)])``.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sbagents import register_extension
from sbagents.errors import UsageError
from sbagents.extensions import Contribution, ExtensionPlan, SpecRecord, TrainingContext, TrainingExtension


@dataclass(frozen=True)
class GradClip:
    """The parsed flag: the largest gradient norm of an update."""

    max_norm: float


class GradClipExtension(TrainingExtension[GradClip]):
    """``--grad-clip X``: the model's ``max_grad_norm`` (PPO, A2C, DQN, ...), recorded in ``args.yml`` and
    ``summary.json``; SB3 only (``--backend rllib`` refuses it in one line)."""

    name = "grad_clip"
    title = "gradient clipping (an example extension)"
    flags = "--grad-clip"
    spec_type = GradClip
    algos = ("a2c", "ppo", "ppo_lstm", "ppo_mask", "dqn", "qrdqn")  # those with a max_grad_norm; others are refused

    def add_arguments(self, group: argparse._ArgumentGroup) -> None:
        group.add_argument("--grad-clip", type=float, default=None, metavar="X",
                           help="largest gradient norm of an update (algorithms with max_grad_norm)")

    def from_args(self, args: argparse.Namespace) -> GradClip | None:
        if args.grad_clip is None:
            return None
        if not args.grad_clip > 0:
            raise UsageError(f"--grad-clip must be > 0, got {args.grad_clip}")
        return GradClip(args.grad_clip)

    def contribute(self, spec: GradClip, plan: ExtensionPlan) -> Contribution:
        return Contribution(model_kwargs={"max_grad_norm": spec.max_norm})

    def finish(self, spec: GradClip, ctx: TrainingContext) -> dict[str, Any]:
        return {"grad_clip": {"max_grad_norm": float(vars(ctx.model)["max_grad_norm"])}}

    def describe(self, summary: Mapping[str, Any], run_dir: Path) -> list[str]:
        clip = summary.get("grad_clip")
        return [f"gradient norm capped at {clip['max_grad_norm']:g}"] if clip else []

    def record(self, spec: GradClip) -> SpecRecord:
        return SpecRecord(args={"grad_clip": spec.max_norm}, flags=["--grad-clip", str(spec.max_norm)])


register_extension(GradClipExtension())
