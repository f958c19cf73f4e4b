"""An adversarial curve and a fairness table from a trained agent, written into BENCHMARKS.md.

Trains the shipped DDPG config on SmartHome (exactly ``python -m sbagents.train --algo ddpg --env
sbagents/SmartHome-v0 --seed 0``), then runs what ``python -m sbagents.evaluate --attack ... --fairness ...``
runs on it, copies ``adversarial.png`` / ``fairness.png`` (and their CSVs) to ``benchmarks/results/``; the tables
come from ``benchmarks/results/trust_report.json``.

    python -m benchmarks run trust-report [--episodes 30]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.report import RESULTS_DIR, recorded_argv
from sbagents.api import EvalOptions, EvaluateOptions, ExecOptions, OutputOptions, RunRef, TrainSpec, evaluate, train

RESULTS = RESULTS_DIR
SECTION = "trust-report"
ENV = "sbagents/SmartHome-v0"
ATTACKS = "gaussian:0.05,0.1,0.2 uniform:0.05,0.1,0.2 fgsm:0.05,0.1,0.2 pgd:0.05,0.1,0.2 critic:0.05,0.1,0.2"
FAIRNESS = "preferred_temp,preferred_light"


def markdown(report: dict[str, Any]) -> str:
    """The adversarial and fairness tables, from the results alone."""
    episodes = report["episodes"]
    lines = [
        "## Trust report: SmartHome DDPG under attack and per user group",
        "",
        f"Commands: `python -m sbagents.train --algo ddpg --env {ENV} --seed 0`, then "
        f"`python -m sbagents.evaluate --algo ddpg --env {ENV} -n {episodes} --attack \"{ATTACKS}\" "
        f"--fairness {FAIRNESS} --json` (`{report['command']}`). eps is in VecNormalize units "
        "(standard deviations of each observation component).",
        "",
        "| attack | eps | mean return | std | success rate |",
        "|---|---:|---:|---:|---:|",
    ]
    for row in report["adversarial"]:
        lines.append(f"| {row['attack']} | {row['eps']:g} | {row['mean_return']:.1f} | {row['std_return']:.1f} | "
                     f"{row['success_rate']:.2f} |")
    lines += ["", "![return vs eps](benchmarks/results/adversarial.png)", ""]
    fair = report["fairness"]
    keys = fair["keys"]
    lines += [f"Success ({fair['metric']}) per bucket of {', '.join(keys)} (Wilson 95% interval):", "",
              "| " + " | ".join(keys) + " | episodes | success | 95% CI |", "|" + "---|" * (len(keys) + 3)]
    for b in fair["buckets"]:
        ranges = [f"{b[f'{k}_low']:g}-{b[f'{k}_high']:g}" for k in keys]
        lines.append("| " + " | ".join(ranges) + f" | {b['n']} | {b['value']:.2f} | "
                     f"{b['ci_low']:.2f}-{b['ci_high']:.2f} |")
    worst = fair["worst"]["value"] if fair["worst"] else float("nan")
    lines += ["", f"Worst bucket {worst:.2f}, max-min gap {fair['gap']:.2f}.",
              "", "![fairness heatmap](benchmarks/results/fairness.png)"]
    return "\n".join(lines)


def run(argv: Sequence[str]) -> dict[str, Any]:
    """``python -m benchmarks run trust-report [--episodes N]``: train, attack and group; copy the plots and CSVs
    into ``benchmarks/results/``; return the tables' figures."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}",
                                     description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--episodes", type=int, default=30)
    args = parser.parse_args(list(argv))
    with tempfile.TemporaryDirectory() as logs:
        train(TrainSpec("ddpg", ENV), OutputOptions(logs), EvalOptions(final_eval_episodes=0),
              ExecOptions(seed=0, verbose=0))
        report = evaluate(RunRef("ddpg", ENV, logs),
                          EvaluateOptions(n_episodes=args.episodes, attacks=ATTACKS, fairness=FAIRNESS))
        run_dir = next(Path(logs).glob("ddpg/*_1"))
        RESULTS.mkdir(exist_ok=True)
        for name in ("adversarial.png", "fairness.png", "adversarial.csv", "fairness.csv"):
            shutil.copy(run_dir / name, RESULTS / name)
    return {"command": " ".join(["python -m benchmarks run", SECTION, *recorded_argv(list(argv))]),
            "episodes": args.episodes, "adversarial": report["adversarial"], "fairness": report["fairness"]}


BENCHMARKS = (
    Benchmark(name=SECTION, kind="suites", results="trust_report.json",
              summary="SmartHome DDPG: return under five attacks and success per user group",
              run=run, render=markdown),
)
