"""``evaluate --attack / --fairness``: adversarial and fairness reports of a finished run (training's trust callbacks
are the extension :class:`sbagents.callbacks.extension.TrustExtension`)."""

from __future__ import annotations

from typing import Any

from sbagents.callbacks import adversarial_report, fairness_report
from sbagents.callbacks.extension import check_attacks, parse_attacks, parse_keys
from sbagents.core.options import EvaluateOptions
from sbagents.core.run_dir import LoadedRun
from sbagents.env_factory import make_eval_vec
from sbagents.errors import UsageError


def trust_report(run: LoadedRun, options: EvaluateOptions) -> dict[str, Any]:
    """Adversarial and fairness evaluation of a finished run (``evaluate --attack/--fairness``): the ``adversarial``
    rows and the ``fairness`` report, written as CSV + PNG into the run dir."""
    model, exp, ref, seed = run.model, run.experiment, run.env, options.seed or 0
    result: dict[str, Any] = {}
    specs = parse_attacks(options.attacks, "--attack")
    keys = parse_keys(options.fairness)
    if specs:
        venv = make_eval_vec(exp, ref, 1, seed, run.stats_path, trust=run.trust)
        try:
            check_attacks(model, venv, specs, "--attack")
            result["adversarial"] = adversarial_report(model, venv, specs, options.n_episodes, run.run_dir, seed=seed)
        finally:
            venv.close()
    if keys:
        venv = make_eval_vec(exp, ref, 1, seed, run.stats_path, trust=run.trust)
        try:
            result["fairness"] = fairness_report(model, venv, keys, options.bins, options.n_episodes, run.run_dir,
                                                 seed=seed)
        except (KeyError, ValueError) as exc:
            raise UsageError(f"--fairness {options.fairness}: {exc}") from None
        finally:
            venv.close()
    return result
