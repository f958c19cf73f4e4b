"""The Ray RLlib backend (``--backend rllib``) behind the :class:`~sbagents.core.backends.Backend` protocol.

Importing this module imports neither Ray nor RLlib: they are imported when a run trains or is evaluated, and a
missing or broken install is one line naming the extra that installs them.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, ClassVar

from sbagents.capabilities import Capability
from sbagents.core.backends import Backend
from sbagents.core.extensions import refused_flags
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
from sbagents.core.run_dir import RunRef
from sbagents.errors import UsageError
from sbagents.rllib import RLLIB_ALGOS, check_kind_algo, check_options, is_rllib_run, require_ray

#: The algorithms only RLlib trains here (no SB3 counterpart in ``train --list``'s rows).
RLLIB_ONLY = ("appo", "impala")
#: ``evaluate`` options RLlib runs do not support -> their flag.
UNSUPPORTED_EVALUATE = {"attacks": "--attack", "fairness": "--fairness", "opponent": "--opponent"}


@contextlib.contextmanager
def rllib_import(what: str) -> Iterator[None]:
    """Importing the RLlib backend (Ray, RLlib and their dependencies): an ``ImportError`` (a Ray without RLlib's
    dependencies, ``No module named 'tree'``) is one line naming the extra that installs them."""
    try:
        yield
    except ImportError as exc:
        raise UsageError(f"{what} cannot import Ray RLlib ({exc}): pip install 'sbagents[distributed]' installs it "
                         "with its dependencies") from None


class RllibBackend(Backend):
    """Ray RLlib (Gymnasium envs and PettingZoo teams; one machine or a Ray cluster with ``--address``)."""

    name: ClassVar[str] = "rllib"
    summary: ClassVar[str] = "Ray RLlib (Gymnasium envs and PettingZoo teams; --address reaches a Ray cluster)"
    algos: ClassVar[tuple[str, ...] | None] = RLLIB_ALGOS

    def capabilities(self) -> list[Capability]:
        """The ``rllib`` column marks the algorithms sbagents' SB3 table has too; ``appo`` and ``impala`` (RLlib's
        own) are named in its legend."""
        shared = tuple(a for a in RLLIB_ALGOS if a not in RLLIB_ONLY)
        return [Capability(self.name, f"--backend {self.name}: {self.summary}; also --algo {', '.join(RLLIB_ONLY)} "
                           "(RLlib's own)", shared, label=f"--backend {self.name}")]

    def train(self, spec: TrainSpec, output: OutputOptions | None, evaluation: EvalOptions | None,
              execution: ExecOptions, callbacks: Sequence[Any], features: Sequence[Any], sb3: Sb3Options,
              rllib: RllibOptions) -> TrainResult:
        from sbagents.core.env_names import resolve_env

        ref = resolve_env(spec.env, spec.gym_packages)
        ref.kind.refuse_backend(ref, self.name)
        refused = refused_flags(features, self.name)
        check_options({"spec": spec, "output": output, "evaluation": evaluation, "execution": execution, "sb3": sb3,
                       "rllib": rllib}, refused)
        check_kind_algo(ref.kind, spec.algo)
        if callbacks:
            raise UsageError("SB3 callbacks do not apply to --backend rllib")
        require_ray()
        with rllib_import("--backend rllib"):
            from sbagents.rllib.training import train_rllib

        return train_rllib(spec, output, evaluation, execution, rllib)

    def owns_run(self, run_dir: Path) -> bool:
        return is_rllib_run(run_dir)

    def record_video(self, run: RunRef, n_steps: int, output_dir: str | Path | None, seed: int,
                     deterministic: bool | None, fps: float | None) -> Path:
        """An mp4 of the run's modules acting (greedy unless ``deterministic`` is False), without starting Ray."""
        self._refuse_run_options(run)
        require_ray("recording an RLlib run")
        with rllib_import("recording an RLlib run"):
            from sbagents.rllib.evaluation import record_run

        assert run.algo is not None
        return record_run(run.run_dir(), run.algo, run.env_ref(), n_steps, output_dir, seed,
                          deterministic is not False, fps, trust=run.trust)

    def export(self, run: RunRef, int8: bool, out: str | Path | None, n_observations: int) -> dict[str, Any]:
        """ONNX export of the run's module (Gymnasium envs), checked against the module as ``evaluate`` plays it."""
        self._refuse_run_options(run)
        require_ray("exporting an RLlib run")
        with rllib_import("exporting an RLlib run"):
            from sbagents.rllib.exporting import export_rllib_run

        assert run.algo is not None
        return export_rllib_run(run.run_dir(), run.algo, run.env_ref(), int8, out, n_observations, trust=run.trust)

    def _refuse_run_options(self, run: RunRef, given: Sequence[str] = ()) -> None:
        """Refuse (one line) run options RLlib runs do not have: a best model, a numbered checkpoint, env kwargs
        (after the command's own ``given`` flags)."""
        given = [*given, *(["--load-best"] if run.load_best else [])]
        given += ["--load-checkpoint"] if run.checkpoint is not None else []
        given += ["--env-kwargs"] if run.env_kwargs else []
        if given:
            raise UsageError(f"{', '.join(given)} not supported for RLlib runs ({run.run_dir()})")

    def evaluate(self, run: RunRef, options: EvaluateOptions) -> dict[str, Any]:
        self._refuse_run_options(run, [flag for name, flag in UNSUPPORTED_EVALUATE.items() if getattr(options, name)])
        require_ray("evaluating an RLlib run")
        with rllib_import("evaluating an RLlib run"):
            from sbagents.rllib.evaluation import evaluate_run

        assert run.algo is not None
        return evaluate_run(run.run_dir(), run.algo, run.env_ref(), options, trust=run.trust)
