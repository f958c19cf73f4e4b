"""The trust callbacks (transparency log, safety counting, attacks and fairness during training) as a training
extension (:mod:`sbagents.extensions`), with their flags, options and console lines."""

from __future__ import annotations

import argparse
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from sbagents.callbacks.adversarial import AdversarialEvalCallback
from sbagents.callbacks.attacks import AttackSpec, ObservationAttacker, parse_attack_spec
from sbagents.callbacks.fairness import FairnessEvalCallback
from sbagents.callbacks.safety import SafetyViolationCallback
from sbagents.callbacks.transparency import TransparencyCSVCallback
from sbagents.core.extensions import ExtensionPlan, SpecRecord, TrainingContext, TrainingExtension, finite
from sbagents.errors import UsageError

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


#: TrustOptions field -> its ``train`` flag (for refusals).
TRUST_FLAGS: dict[str, str] = {
    "transparency_log": "--transparency-log", "safety": "--safety", "cost_limit": "--cost-limit",
    "max_violations": "--max-violations", "adversarial": "--adversarial-eval", "fairness": "--fairness",
    "bins": "--bins", "book_header": "--transparency-format",
}


@dataclass(frozen=True, kw_only=True)
class TrustOptions:
    """What the ``train`` trust flags asked for.

    :param transparency_log: CSV path (``""``: ``<run dir>/transparency.csv``; ``None``: off; ``.csv.gz`` compresses).
    :param safety: count violations (``safety.json``), stopping at ``cost_limit``/``max_violations``.
    :param cost_limit: stop when the mean episode cost passes it (with ``--constraint``: the limit trained for).
    :param max_violations: stop after this many violation steps.
    :param adversarial: attack spec string evaluated every ``eval_freq`` (``adversarial.csv`` + ``.png``).
    :param fairness: comma-separated info keys to bucket episodes by (``fairness.csv`` + ``.png``).
    :param bins: buckets per fairness key.
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

    def given_flags(self) -> list[str]:
        """The flags of the fields that differ from their defaults."""
        default = TrustOptions()
        return [TRUST_FLAGS[f.name] for f in fields(self) if getattr(self, f.name) != getattr(default, f.name)]

    def command_args(self) -> list[str]:
        """The ``train`` arguments that ask for these options (the fields that differ from their defaults)."""
        args: list[str] = []
        default = TrustOptions()
        for f in fields(self):
            value = getattr(self, f.name)
            if value == getattr(default, f.name):
                continue
            if f.name == "book_header":
                args += [TRUST_FLAGS[f.name], "book"]
            elif isinstance(value, bool) or value == "":  # --safety; --transparency-log without a path
                args.append(TRUST_FLAGS[f.name])
            else:
                args += [TRUST_FLAGS[f.name], str(value)]
        return args


def check_attacks(model: BaseAlgorithm, venv: VecEnv, specs: list[AttackSpec], flag: str) -> None:
    """Raise :class:`UsageError` naming ``flag`` when an attack cannot run against ``model`` on ``venv``."""
    for spec in specs:
        try:
            ObservationAttacker(model.policy, venv, spec)
        except ValueError as exc:
            raise UsageError(f"{flag} {spec.label}: {exc}") from None


def trust_callbacks(opts: TrustOptions, ctx: TrainingContext) -> list[BaseCallback]:
    """The callbacks the options ask for, writing into the run dir (attacks are checked against the model)."""
    run_dir, seed = ctx.run_dir, ctx.seed
    callbacks: list[BaseCallback] = []
    if opts.transparency_log is not None:
        path = Path(opts.transparency_log) if opts.transparency_log else run_dir / DEFAULT_TRANSPARENCY_FILE
        path = path.with_name(ctx.file_name(path.name))  # a group's model: transparency.<group>.csv
        callbacks.append(TransparencyCSVCallback(str(path), book_header=opts.book_header))
    if opts.count_violations:
        safety = run_dir if ctx.group is None else run_dir / ctx.file_name("safety.json")
        callbacks.append(SafetyViolationCallback(opts.cost_limit, opts.max_violations, path=str(safety), verbose=0))
    freq = ctx.calls(ctx.eval_freq) if ctx.eval_freq > 0 else ctx.exp.n_timesteps
    if opts.adversarial:
        venv = ctx.make_eval_env(1, seed + ADVERSARIAL_SEED_OFFSET)
        specs = parse_attacks(opts.adversarial, "--adversarial-eval")
        check_attacks(ctx.model, venv, specs, "--adversarial-eval")
        callbacks.append(AdversarialEvalCallback(venv, specs, eval_freq=freq, n_eval_episodes=ctx.eval_episodes,
                                                 path=str(run_dir), seed=seed + ADVERSARIAL_SEED_OFFSET))
    if opts.fairness:
        callbacks.append(FairnessEvalCallback(
            ctx.make_eval_env(1, seed + FAIRNESS_SEED_OFFSET), parse_keys(opts.fairness), bins=opts.bins,
            eval_freq=freq, n_eval_episodes=max(ctx.eval_episodes, 30), path=str(run_dir),
            seed=seed + FAIRNESS_SEED_OFFSET))
    return callbacks


def trust_results(callbacks: Sequence[BaseCallback]) -> dict[str, Any]:
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


def trust_summary_lines(results: Mapping[str, Any]) -> list[str]:
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


class TrustExtension(TrainingExtension[TrustOptions]):
    """``--transparency-log``, ``--safety``, ``--cost-limit``, ``--max-violations``, ``--adversarial-eval``,
    ``--fairness``: the trust callbacks of a run (their files in the run dir, their results on the console).
    Runs of one model per group get the transparency and safety callbacks per group (``transparency.<group>.csv``,
    ``safety.<group>.json``); attacks and fairness evaluate one model and are refused there."""

    name = "trust"
    title = "trust (sbagents.callbacks)"
    flags = "the trust flags"
    spec_type = TrustOptions

    def add_arguments(self, group: argparse._ArgumentGroup) -> None:
        group.add_argument("--transparency-log", nargs="?", const="", default=None, metavar="PATH",
                           help="CSV of every decision (default <run dir>/transparency.csv; .csv.gz compresses)")
        group.add_argument("--transparency-format", choices=["full", "book"], default="full",
                           help="full: every obs/action/info column; book: the book's header (SmartHome)")
        group.add_argument("--safety", action="store_true", help="count safety violations (safety.json, TensorBoard)")
        group.add_argument("--cost-limit", type=float, default=None,
                           help="stop when the mean episode cost passes X (with --constraint: the limit trained for)")
        group.add_argument("--max-violations", type=int, default=None, help="stop after N violations")
        group.add_argument("--adversarial-eval", default=None, metavar="SPEC",
                           help='attacks evaluated during training, e.g. "gaussian:0.05,0.1 fgsm:0.01,0.05"')
        group.add_argument("--fairness", default=None, metavar="KEYS",
                           help="info keys to bucket episodes by, e.g. object_scale,object_mass")
        group.add_argument("--bins", type=int, default=3, help="buckets per fairness key")

    def from_args(self, args: argparse.Namespace) -> TrustOptions | None:
        spec = TrustOptions(transparency_log=args.transparency_log, safety=args.safety, cost_limit=args.cost_limit,
                            max_violations=args.max_violations, adversarial=args.adversarial_eval,
                            fairness=args.fairness, bins=args.bins,
                            book_header=args.transparency_format == "book")
        return spec if self.is_active(spec) else None

    def is_active(self, spec: TrustOptions) -> bool:
        return bool(spec.given_flags())

    def configure(self, spec: TrustOptions | None, plan: ExtensionPlan) -> TrustOptions | None:
        if spec is not None and plan.n_models > 1 and (spec.adversarial or spec.fairness):
            raise UsageError("--adversarial-eval and --fairness support policies: shared (one model); this run "
                             "trains one model per group")
        return spec

    def record(self, spec: TrustOptions) -> SpecRecord:
        return SpecRecord(flags=spec.command_args())

    def callbacks(self, spec: TrustOptions, ctx: TrainingContext) -> list[BaseCallback]:
        callbacks = trust_callbacks(spec, ctx)
        ctx.state[self.name] = callbacks
        return callbacks

    def finish(self, spec: TrustOptions, ctx: TrainingContext) -> dict[str, Any]:
        return finite(trust_results(ctx.state.get(self.name, [])))

    def describe(self, summary: Mapping[str, Any], run_dir: Path) -> list[str]:
        return trust_summary_lines(summary)
