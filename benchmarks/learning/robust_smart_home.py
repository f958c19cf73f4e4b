"""Robust SmartHome agents: vanilla TD3 beside the SA regularizer, adversarial rollouts and their combination.

Every run is ``python -m sbagents.train --algo td3 --env sbagents/SmartHome-v0 --seed S [-n N] [--robust SPEC]
[-conf CONFIG]`` (the same library call), then ``python -m sbagents.evaluate ... -n EPISODES --attack "pgd:0.2
critic:0.2"`` on the final model: success (the env's comfort criterion, ``is_success``) and mean return, clean and
under each attack (eps in VecNormalize standard deviations). Train time is the run's ``summary.json``
(``train_seconds`` wall, ``train_cpu_seconds`` process CPU); the ratio is to the vanilla run of the same seed. Issue
19's bar: clean success >= 0.97 and >= 0.9 under both attacks, in <= 3x the vanilla training time.

    python -m benchmarks run robust-smart-home [--seeds 0 1 2] [--episodes 30] [--variants vanilla sa adv best ...]
    python -m benchmarks render robust-smart-home   # the section from benchmarks/results/robust_smart_home.json
"""

from __future__ import annotations

import argparse
import os
import shlex
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from statistics import mean
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.learning.seed_table import StatsRow, grouped_stats_table, stats_of
from benchmarks.report import recorded_argv

ENV = "sbagents/SmartHome-v0"
ALGO = "td3"
ATTACKS = "pgd:0.2 critic:0.2"
SECTION = "robust-smart-home"
NOTES = ("How `best` was chosen: kappa on seed 0 (scratch runs, 10 episodes) among SA with kappa 1, 0.3 and 0.1 at "
         "2-2.5x the budget, the critic-aware term (`qdrop=1`) and SA plus critic-attack rollouts (`sa+adv`). An "
         "earlier run of this benchmark with 5 PGD steps (`sa:0.2,kappa=0.1`, 16k) also scored 1.00 / 1.00 / 1.00 on "
         "every seed but took 2.78 / 3.27 / 2.82x the vanilla CPU time, and 12k steps fell to 0.70 PGD / 0.60 critic "
         "on seed 0, hence 3 PGD steps at 16k. `vanilla-16k` is the control: the budget without robust training. "
         "Why it works: under attack no policy avoids a steady temperature error of about eps x (std of the "
         "temperature + std of the preferred temperature), about 0.73 C of the 1 C tolerance (the attacker makes the "
         "state look on target); what fails the criterion is a gain above 1 from temperature error to action (the "
         "attacker pumps an overshoot) or a low gain with an offset at the target. kappa 1 flattened the gain (mean "
         "0.24 on seed 0), kappa 0.1 kept it at 0.5-0.7 with an offset below 0.07 C; vanilla reached 1.7.")


@dataclass(frozen=True)
class Variant:
    """One row group: ``--robust`` spec (None: plain TD3), budget (None: the config's) and config file (None: the
    shipped ``zoo_configs/td3.yml``)."""

    robust: str | None = None
    n_timesteps: int | None = None
    conf_file: str | None = None

    def command(self, seed: int) -> str:
        """The equivalent ``train`` command line."""
        parts = [f"python -m sbagents.train --algo {ALGO} --env {ENV} --seed {seed}"]
        parts += [f"-conf {self.conf_file}"] if self.conf_file else []
        parts += [f"-n {self.n_timesteps}"] if self.n_timesteps else []
        parts += [f"--robust {self.robust}"] if self.robust else []
        return " ".join(parts)


VARIANTS: dict[str, Variant] = {
    "vanilla": Variant(),
    "sa": Variant("sa:0.2"),
    "adv": Variant("adv:0.2"),
    "best": Variant("sa:0.2,kappa=0.1,steps=3", 16000),
    "vanilla-16k": Variant(None, 16000),  # control: the best variant's budget without robust training
}


def run_one(name: str, variant: Variant, seed: int, episodes: int, logs: str) -> dict[str, Any]:
    """Train and evaluate one variant on one seed."""
    from sbagents.api import (
        EvalOptions,
        EvaluateOptions,
        ExecOptions,
        OutputOptions,
        RunRef,
        TrainSpec,
        evaluate,
        parse_robust,
        train,
    )

    folder = os.path.join(logs, f"{name}_{seed}")
    load = os.getloadavg()[0]
    result = train(TrainSpec(ALGO, ENV, n_timesteps=variant.n_timesteps, conf_file=variant.conf_file),
                   OutputOptions(folder, command=variant.command(seed)),
                   EvalOptions(eval_freq=0, final_eval_episodes=0), ExecOptions(seed=seed, verbose=0),
                   features=[parse_robust(variant.robust)] if variant.robust else [])
    report = evaluate(RunRef(ALGO, ENV, folder), EvaluateOptions(n_episodes=episodes, attacks=ATTACKS))
    row: dict[str, Any] = {"variant": name, "seed": seed, "n_timesteps": result.summary["n_timesteps"],
                           "train_s": result.summary["train_seconds"],
                           "train_cpu_s": result.summary["train_cpu_seconds"], "load": round(load, 2)}
    for r in report["adversarial"]:
        row[f"{r['attack']}_success"], row[f"{r['attack']}_return"] = r["success_rate"], r["mean_return"]
    return row


def _ratios(rows: list[dict[str, Any]]) -> None:
    vanilla = {r["seed"]: r for r in rows if r["variant"] == "vanilla"}
    for r in rows:
        base = vanilla.get(r["seed"])
        r["time_ratio"] = r["train_s"] / base["train_s"] if base else None
        r["cpu_ratio"] = r["train_cpu_s"] / base["train_cpu_s"] if base else None


def meets_bar(r: dict[str, Any]) -> bool:
    """Issue 19's bar for one row (or a mean row); the CPU-time ratio decides the time part."""
    return (r["none_success"] >= 0.97 and r["pgd_success"] >= 0.9 and r["critic_success"] >= 0.9
            and r["cpu_ratio"] is not None and r["cpu_ratio"] <= 3.0)


def mean_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One mean row per variant (over its seeds)."""
    out = []
    for name in dict.fromkeys(r["variant"] for r in rows):
        group = [r for r in rows if r["variant"] == name]
        keys = [k for k, v in group[0].items() if isinstance(v, float | int) and k != "seed"]
        avg: dict[str, Any] = {"variant": name, "seed": "mean"}
        for k in keys:
            values = [r[k] for r in group if r[k] is not None]
            avg[k] = mean(values) if len(values) == len(group) else None
        out.append(avg)
    return out


def _fmt(value: Any, spec: str) -> str:
    return "" if value is None else format(value, spec)


def markdown(result: dict[str, Any]) -> str:
    """The BENCHMARKS.md section."""
    lines = ["## Robust SmartHome agents: TD3 vs SA regularizer vs adversarial rollouts under attack", "",
             f"Command: `{result['command']}` ({result['wall_s'] / 60:.0f} min wall). Machine: 2 cores "
             "shared with other jobs (the `load` column is the 1-minute load average when the run started), torch "
             f"1 thread. Each run: `python -m sbagents.evaluate --algo {ALGO} --env {ENV} -n {result['episodes']} "
             f"--attack \"{ATTACKS}\"` after training with:", ""]
    for name in result["variants"]:
        command = Variant(**result["variant_specs"][name]).command(0).replace("--seed 0", "--seed S")
        lines.append(f"- **{name}**: `{command}`")
    lines += ["", "Success = share of episodes meeting the env's comfort criterion (`is_success`); eps in VecNormalize "
              "standard deviations. Train time ratio to the vanilla run of the same seed (wall / process CPU). "
              "Bar (issue 19): clean >= 0.97, PGD and critic >= 0.9, CPU time <= 3x vanilla.", "",
              "| variant | seed | steps | train s | ratio (wall / cpu) | load | clean | PGD 0.2 | critic 0.2 | "
              "return clean / PGD / critic | bar |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in [*result["runs"], *result["means"]]:
        ratio = f"{_fmt(r['time_ratio'], '.2f')} / {_fmt(r['cpu_ratio'], '.2f')}"
        returns = " / ".join(_fmt(r[f"{a}_return"], ".1f") for a in ("none", "pgd", "critic"))
        seed = f"**{r['seed']}**" if r["seed"] == "mean" else str(r["seed"])
        lines.append(f"| {r['variant']} | {seed} | {r['n_timesteps']:.0f} | {r['train_s']:.0f} | {ratio} | "
                     f"{r['load']:.1f} | {r['none_success']:.2f} | {r['pgd_success']:.2f} | "
                     f"{r['critic_success']:.2f} | {returns} | {'met' if meets_bar(r) else 'not met'} |")
    rows: list[StatsRow] = [(name, f"{label} success", result["stats"][name][key], ".2f")
                            for name in result["variants"] for key, label in SUCCESS.items()]
    lines += ["", *grouped_stats_table("variant", rows), "", NOTES]
    return "\n".join(lines)


#: The success metrics of the over-seeds table: row key -> label.
SUCCESS = {"none_success": "clean", "pgd_success": "PGD 0.2", "critic_success": "critic 0.2"}


def add_stats(result: dict[str, Any]) -> dict[str, Any]:
    """``result`` with ``stats[variant][metric]``: the clean, PGD and critic success over seeds."""
    stats = {name: {key: stats_of([r[key] for r in result["runs"] if r["variant"] == name]) for key in SUCCESS}
             for name in result["variants"]}
    return {**result, "stats": stats}


def build_parser() -> argparse.ArgumentParser:
    """The benchmark's options."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}",
                                     description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS))
    parser.add_argument("-n", "--n-timesteps", type=int, default=None,
                        help="every variant's budget (default: each variant's own; a smaller one checks the "
                             "benchmark, it does not measure it)")
    return parser


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Train and evaluate every (seed, variant); the results of the section."""
    args = build_parser().parse_args(list(argv))
    variants = {name: replace(VARIANTS[name], n_timesteps=args.n_timesteps or VARIANTS[name].n_timesteps)
                for name in args.variants}
    start = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory() as logs:
        for seed in args.seeds:
            for name in args.variants:
                rows.append(run_one(name, variants[name], seed, args.episodes, logs))
                print(rows[-1], flush=True)
    _ratios(rows)
    command = shlex.join(["python", "-m", "benchmarks", "run", SECTION, *recorded_argv(list(argv))])
    return add_stats({"command": command, "seeds": args.seeds, "episodes": args.episodes, "variants": args.variants,
                      "variant_specs": {n: asdict(variants[n]) for n in args.variants}, "runs": rows,
                      "means": mean_rows(rows), "wall_s": time.perf_counter() - start})


BENCHMARKS = (
    Benchmark(name=SECTION, kind="learning", results="robust_smart_home.json",
              summary="SmartHome TD3 vs SA regularizer vs adversarial rollouts: success under PGD and critic attacks",
              run=run, render=markdown),
)
