"""The default backend, Stable-Baselines3 (``--backend sb3``): :func:`~sbagents.pipeline.training.train_sb3` and
:func:`~sbagents.pipeline.evaluation.evaluate_sb3_run` behind the :class:`~sbagents.core.backends.Backend`
protocol."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar

from sbagents.core.backends import Backend
from sbagents.core.lifecycle import TrainResult
from sbagents.core.options import (
    EvalOptions,
    EvaluateOptions,
    ExecOptions,
    OutputOptions,
    RllibOptions,
    Sb3Options,
    TrainSpec,
)
from sbagents.core.run_dir import RunRef, load_run
from sbagents.errors import UsageError


class Sb3Backend(Backend):
    """SB3 and sb3-contrib algorithms on every env kind, in this process (``--vec-env`` picks the vec env)."""

    name: ClassVar[str] = "sb3"
    summary: ClassVar[str] = "Stable-Baselines3 / sb3-contrib in this process (every env kind)"

    def train(self, spec: TrainSpec, output: OutputOptions | None, evaluation: EvalOptions | None,
              execution: ExecOptions, callbacks: Sequence[Any], features: Sequence[Any], sb3: Sb3Options,
              rllib: RllibOptions) -> TrainResult:
        from sbagents.pipeline.training import train_sb3

        if rllib != RllibOptions():
            raise UsageError("--address and --num-env-runners need --backend rllib")
        return train_sb3(spec, output, evaluation, execution, callbacks, features, sb3)

    def owns_run(self, run_dir: Path) -> bool:
        return True  # the default: any run dir no other backend claims

    def evaluate(self, run: RunRef, options: EvaluateOptions) -> dict[str, Any]:
        from sbagents.pipeline.evaluation import evaluate_sb3_run

        return evaluate_sb3_run(load_run(run), options)
