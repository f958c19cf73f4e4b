"""The one place that picks the training library: SB3 (:mod:`sbagents.pipeline.training`) or Ray RLlib
(:mod:`sbagents.rllib`), for training (``execution.backend``) and for evaluating a finished run (an RLlib run dir
holds ``rllib_checkpoint/``). Nothing of :mod:`sbagents.rllib` is imported for an SB3 run, and Ray only when a run
asks for RLlib.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

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
from sbagents.extensions import activate
from sbagents.pipeline.evaluation import evaluate_sb3_run
from sbagents.pipeline.training import train_sb3
from sbagents.pipeline.trust import parse_attacks


def train(
    spec: TrainSpec,
    output: OutputOptions | None = None,
    evaluation: EvalOptions | None = None,
    execution: ExecOptions | None = None,
    callbacks: Sequence[BaseCallback] = (),
    features: Sequence[Any] = (),
    *,
    sb3: Sb3Options | None = None,
    rllib: RllibOptions | None = None,
) -> TrainResult:
    """Train ``spec.algo`` on ``spec.env`` and write a run directory (``python -m sbagents.train``).

    :param spec: what to train.
    :param output: where to write (default: ``logs/``).
    :param evaluation: periodic and final evaluation.
    :param execution: seed, backend (``sb3`` or ``rllib``), device, threads, verbosity.
    :param callbacks: extra SB3 callbacks (SB3 only).
    :param features: specs of training extensions (:mod:`sbagents.extensions`), e.g. ``TrustOptions(safety=True)``
        (transparency log, safety counting, attacks and fairness), ``PrivacyOptions(epsilon=8)`` (DP-SGD),
        ``parse_robust("sa:0.1")``, ``ConstraintSpec("pid", 0.1)``, ``ReplayBufferOptions(save=True)``; a
        backend refuses in one line the features it cannot honour.
    :param sb3: what only SB3 runs use (vec env, log interval); RLlib refuses any that is not the default.
    :param rllib: what only RLlib runs use (env runners, Ray address); SB3 refuses any that is not the default.
    :return: the run dir, the model (SB3) and the summary; ``interrupted`` after Ctrl-C/SIGTERM.
    """
    execution, sb3, rllib = execution or ExecOptions(), sb3 or Sb3Options(), rllib or RllibOptions()
    for group in (execution, sb3, rllib):
        group.validate()
    if execution.backend == "sb3" and rllib != RllibOptions():
        raise UsageError("--address and --num-env-runners need --backend rllib")
    if execution.backend == "rllib":
        from sbagents.core.env_names import resolve_env
        from sbagents.rllib import check_options, require_ray

        ref = resolve_env(spec.env, spec.gym_packages)
        ref.kind.refuse_backend(ref, "rllib")
        refused = [flag for a in activate(features) for flag in a.extension.unsupported_flags(a.spec, "rllib")]
        check_options({"spec": spec, "output": output, "evaluation": evaluation, "execution": execution, "sb3": sb3,
                       "rllib": rllib}, refused)
        if callbacks:
            raise UsageError("SB3 callbacks do not apply to --backend rllib")
        require_ray()
        with _rllib_import("--backend rllib"):
            from sbagents.rllib.training import train_rllib

        return train_rllib(spec, output, evaluation, execution, rllib)
    return train_sb3(spec, output, evaluation, execution, callbacks, features, sb3)


@contextlib.contextmanager
def _rllib_import(what: str) -> Iterator[None]:
    """Importing the RLlib backend (Ray, RLlib and their dependencies): an ``ImportError`` (a Ray without RLlib's
    dependencies, ``No module named 'tree'``) is one line naming the extra that installs them."""
    try:
        yield
    except ImportError as exc:
        raise UsageError(f"{what} cannot import Ray RLlib ({exc}): pip install 'sbagents[distributed]' installs it "
                         "with its dependencies") from None


#: ``evaluate`` options RLlib runs do not support -> their flag.
_RLLIB_UNSUPPORTED = {"attacks": "--attack", "fairness": "--fairness", "opponent": "--opponent"}


def evaluate(run: RunRef, options: EvaluateOptions | None = None) -> dict[str, Any]:
    """Evaluate a finished run of ``python -m sbagents.train`` (RL Zoo's ``enjoy``), whichever backend made it.

    :return: the ``evaluate --json`` summary (with ``adversarial`` / ``fairness`` when the options ask for them;
        their CSV + PNG files are written into the run dir).
    """
    from sbagents.rllib import is_rllib_run, require_ray  # light: no Ray is imported

    options = options or EvaluateOptions()
    options.validate()
    parse_attacks(options.attacks, "--attack")
    run_dir = run.run_dir()
    if is_rllib_run(run_dir):  # python -m sbagents.train --backend rllib
        given = [flag for name, flag in _RLLIB_UNSUPPORTED.items() if getattr(options, name)]
        given += ["--load-best"] if run.load_best else []
        given += ["--load-checkpoint"] if run.checkpoint is not None else []
        given += ["--env-kwargs"] if run.env_kwargs else []
        if given:
            raise UsageError(f"{', '.join(given)} not supported for RLlib runs ({run_dir})")
        require_ray("evaluating an RLlib run")
        with _rllib_import("evaluating an RLlib run"):
            from sbagents.rllib.evaluation import evaluate_run

        assert run.algo is not None
        return evaluate_run(run_dir, run.algo, run.env_ref(), options, trust=run.trust)
    return evaluate_sb3_run(load_run(run), options)
