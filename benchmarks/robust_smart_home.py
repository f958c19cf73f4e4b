"""Robust SmartHome agents: vanilla TD3 beside the SA regularizer, adversarial rollouts and their combination.

Every run is ``python -m sbagents.train --algo td3 --env sbagents/SmartHome-v0 --seed S [-n N] [--robust SPEC]
[-conf CONFIG]`` (the same library call), then ``python -m sbagents.evaluate ... -n EPISODES --attack "pgd:0.2
critic:0.2"`` on the final model: success (the env's comfort criterion, ``is_success``) and mean return, clean and
under each attack (eps in VecNormalize standard deviations). Train time is the run's ``summary.json``
(``train_seconds`` wall, ``train_cpu_seconds`` process CPU); the ratio is to the vanilla run of the same seed. Issue
19's bar: clean success >= 0.97 and >= 0.9 under both attacks, in <= 3x the vanilla training time.

    python -m benchmarks.robust_smart_home [--seeds 0 1 2] [--episodes 30] [--variants vanilla sa adv best ...]
    python -m benchmarks.robust_smart_home --render benchmarks/results/robust_smart_home.json  # text only
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from statistics import mean
from typing import Any

from benchmarks.report import publish
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


def run(name: str, variant: Variant, seed: int, episodes: int, logs: str) -> dict[str, Any]:
    """Train and evaluate one variant on one seed."""
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
    seeds = " ".join(str(s) for s in result["seeds"])
    lines = ["## Robust SmartHome agents: TD3 vs SA regularizer vs adversarial rollouts under attack", "",
             f"Command: `python -m benchmarks.robust_smart_home --seeds {seeds} --episodes {result['episodes']} "
             f"--variants {' '.join(result['variants'])}` ({result['wall_s'] / 60:.0f} min wall). Machine: 2 cores "
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
    lines += ["", NOTES]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS))
    parser.add_argument("--write", default="BENCHMARKS.md", help="markdown file to update ('' for none)")
    parser.add_argument("--json", default="benchmarks/results/robust_smart_home.json", help="raw results ('' for none)")
    parser.add_argument("--render", default=None, metavar="JSON",
                        help="only rewrite the section from a results JSON of an earlier run")
    args = parser.parse_args(argv)
    if args.render:
        result = json.loads(Path(args.render).read_text())
        publish(markdown(result), result, args.write, None, SECTION)
        return result
    start = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory() as logs:
        for seed in args.seeds:
            for name in args.variants:
                rows.append(run(name, VARIANTS[name], seed, args.episodes, logs))
                print(json.dumps(rows[-1]), flush=True)
    _ratios(rows)
    result = {"seeds": args.seeds, "episodes": args.episodes, "variants": args.variants,
              "variant_specs": {n: asdict(VARIANTS[n]) for n in args.variants}, "runs": rows,
              "means": mean_rows(rows), "wall_s": time.perf_counter() - start}
    publish(markdown(result), result, args.write, args.json, SECTION)
    return result


if __name__ == "__main__":
    main()
