"""Wiring the trust callbacks (transparency, safety, adversarial, fairness) into ``train`` and ``evaluate``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from sbagents.callbacks import (
    AdversarialEvalCallback,
    AttackSpec,
    FairnessEvalCallback,
    ObservationAttacker,
    SafetyViolationCallback,
    TransparencyCSVCallback,
    adversarial_report,
    fairness_report,
    parse_attack_spec,
)
from sbagents.core.options import EvaluateOptions
from sbagents.core.run_dir import LoadedRun
from sbagents.env_factory import make_eval_vec
from sbagents.errors import UsageError
from sbagents.pipeline.models import RunContext

DEFAULT_TRANSPARENCY_FILE = "transparency.csv"
#: Seed offsets of the attack and fairness evaluation envs (distinct from training and periodic evaluation).
ADVERSARIAL_SEED_OFFSET = 20_000
FAIRNESS_SEED_OFFSET = 30_000


def parse_attacks(spec: str | None, flag: str) -> list[AttackSpec]:
    """``"gaussian:0.05,0.1 fgsm:0.01"`` -> attack specs, or :class:`UsageError` naming the flag."""
    if not spec:
        return []
    try:
        return parse_attack_spec(spec)
    except ValueError as exc:
        raise UsageError(f"{flag}: {exc}") from None


def parse_keys(spec: str | None) -> list[str]:
    """``"object_scale,object_mass"`` -> ``["object_scale", "object_mass"]``."""
    return [k.strip() for k in (spec or "").split(",") if k.strip()]


@dataclass
class TrustOptions:
    """What the ``train`` trust flags asked for.

    :param transparency_log: CSV path (``""``: ``<run dir>/transparency.csv``; ``None``: off; ``.csv.gz`` compresses).
    :param safety: count violations (``safety.json``), stopping at ``cost_limit``/``max_violations``.
    :param adversarial: attack spec string evaluated every ``eval_freq`` (``adversarial.csv`` + ``.png``).
    :param fairness: comma-separated info keys to bucket episodes by (``fairness.csv`` + ``.png``).
    :param book_header: transparency CSV in the book's layout (SmartHome: ``Episode, Step, Temperature, ...``).
    """

    transparency_log: str | None = None
    safety: bool = False
    cost_limit: float | None = None
    max_violations: int | None = None
    adversarial: str | None = None
    fairness: str | None = None
    bins: int = 3
    book_header: bool = False

    def validate(self) -> None:
        """Check the specs before a run dir exists."""
        parse_attacks(self.adversarial, "--adversarial-eval")
        if self.bins < 1:
            raise UsageError(f"--bins must be >= 1, got {self.bins}")

    @property
    def count_violations(self) -> bool:
        """Safety counting is on with ``--safety`` or any of its limits."""
        return self.safety or self.cost_limit is not None or self.max_violations is not None


def check_attacks(model: BaseAlgorithm, venv: VecEnv, specs: list[AttackSpec], flag: str) -> None:
    """Raise :class:`UsageError` naming ``flag`` when an attack cannot run against ``model`` on ``venv``."""
    for spec in specs:
        try:
            ObservationAttacker(model.policy, venv, spec)
        except ValueError as exc:
            raise UsageError(f"{flag} {spec.label}: {exc}") from None


def trust_callbacks(opts: TrustOptions, ctx: RunContext) -> list[BaseCallback]:
    """The callbacks the options ask for, writing into the run dir (attacks are checked against the model)."""
    exp, ref, run_dir, seed = ctx.exp, ctx.ref, ctx.run_dir, ctx.seed
    callbacks: list[BaseCallback] = []
    if opts.transparency_log is not None:
        path = Path(opts.transparency_log) if opts.transparency_log else run_dir / DEFAULT_TRANSPARENCY_FILE
        callbacks.append(TransparencyCSVCallback(str(path), book_header=opts.book_header))
    if opts.count_violations:
        callbacks.append(SafetyViolationCallback(opts.cost_limit, opts.max_violations, path=str(run_dir), verbose=0))
    freq = ctx.calls(ctx.eval_freq) if ctx.eval_freq > 0 else exp.n_timesteps
    if opts.adversarial:
        venv = make_eval_vec(exp, ref, 1, seed + ADVERSARIAL_SEED_OFFSET)
        specs = parse_attacks(opts.adversarial, "--adversarial-eval")
        check_attacks(ctx.model, venv, specs, "--adversarial-eval")
        callbacks.append(AdversarialEvalCallback(venv, specs, eval_freq=freq, n_eval_episodes=ctx.eval_episodes,
                                                 path=str(run_dir), seed=seed + ADVERSARIAL_SEED_OFFSET))
    if opts.fairness:
        callbacks.append(FairnessEvalCallback(
            make_eval_vec(exp, ref, 1, seed + FAIRNESS_SEED_OFFSET), parse_keys(opts.fairness), bins=opts.bins,
            eval_freq=freq, n_eval_episodes=max(ctx.eval_episodes, 30), path=str(run_dir),
            seed=seed + FAIRNESS_SEED_OFFSET))
    return callbacks


def trust_results(callbacks: list[BaseCallback]) -> dict[str, Any]:
    """The final results of the trust callbacks of a run: ``safety`` (the ``safety.json`` content),
    ``adversarial`` (the last evaluation's rows) and ``fairness`` (the last report), for those present."""
    results: dict[str, Any] = {}
    for cb in callbacks:
        if isinstance(cb, SafetyViolationCallback):
            results["safety"] = cb.summary()
        elif isinstance(cb, AdversarialEvalCallback) and cb.last_results:
            results["adversarial"] = cb.last_results
        elif isinstance(cb, FairnessEvalCallback) and cb.last_report is not None:
            results["fairness"] = cb.last_report
    return results


def _bucket_label(bucket: dict[str, Any], keys: list[str]) -> str:
    return ", ".join(f"{k} {bucket[f'{k}_low']:.3g}-{bucket[f'{k}_high']:.3g}" for k in keys)


def trust_summary_lines(results: dict[str, Any]) -> list[str]:
    """One line per trust result (see :func:`trust_results`; also the ``evaluate`` keys ``adversarial`` and
    ``fairness``): violations, returns under each attack, the worst fairness bucket."""
    lines: list[str] = []
    safety = results.get("safety")
    if safety is not None:
        kinds = ", ".join(f"{k} {n}" for k, n in safety["violations"].items())
        text = (f"safety: {safety['total_violations']} violation steps{f' ({kinds})' if kinds else ''} in "
                f"{safety['total_steps']:,} steps ({safety['violation_rate']:.3g} per 1,000)")
        if safety["ep_cost"]["mean"] is not None:
            text += f", mean episode cost {safety['ep_cost']['mean']:.3g}"
        if safety["stopped"]:
            text += f"; {safety['stop_reason']}"
        lines.append(text)
    rows = results.get("adversarial")
    if rows:
        parts = []
        for row in rows:
            label = "clean" if row["attack"] == "none" else row["label"]
            success = row.get("success_rate")
            extra = f" (success {success:.2f})" if success is not None and success == success else ""
            parts.append(f"{label} {row['mean_return']:.2f}{extra}")
        lines.append("mean return under attack: " + ", ".join(parts))
    fair = results.get("fairness")
    if fair is not None and fair.get("worst") is not None:
        worst = fair["worst"]
        lines.append(
            f"fairness ({fair['metric']} by {', '.join(fair['keys'])}): worst bucket {worst['value']:.3g} "
            f"[{worst['ci_low']:.3g}, {worst['ci_high']:.3g}] at {_bucket_label(worst, fair['keys'])} "
            f"(n={worst['n']}), gap {fair['gap']:.3g}"
        )
    return lines


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
