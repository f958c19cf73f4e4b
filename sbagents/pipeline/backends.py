"""Training and evaluating through whichever backend (:mod:`sbagents.core.backends`) a run names or was made by:
``execution.backend`` for training, :func:`~sbagents.core.backends.backend_of_run` for a finished run dir. This
module names no backend; Ray is imported only when a run asks for RLlib.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

from sbagents.core.backends import backend_of_run, get_backend
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
    :param execution: seed, backend (a :func:`~sbagents.core.backends.backend_names` name), device, threads,
        verbosity.
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
    backend = get_backend(execution.backend)
    return backend.train(spec, output, evaluation, execution, callbacks, features, sb3, rllib)


def evaluate(run: RunRef, options: EvaluateOptions | None = None) -> dict[str, Any]:
    """Evaluate a finished run of ``python -m sbagents.train`` (RL Zoo's ``enjoy``), whichever backend made it
    (:func:`~sbagents.core.backends.backend_of_run`).

    :return: the ``evaluate --json`` summary (with ``adversarial`` / ``fairness`` when the options ask for them;
        their CSV + PNG files are written into the run dir).
    """
    options = options or EvaluateOptions()
    options.validate()
    parse_attacks(options.attacks, "--attack")
    return backend_of_run(run.run_dir()).evaluate(run, options)
