"""Learning results with the shipped zoo configs: train on several seeds, evaluate the greedy policy.

Each run is exactly ``python -m sbagents.train --algo A --env E --seed S --final-eval-episodes N`` (the same
library call), so ``train_seconds`` is the wall time of ``model.learn`` and the evaluation is the run's
``summary.json``. Results go to ``benchmarks/results/learning_<env>_<algo>.json`` and a Markdown table is printed.

Usage::

    python -m benchmarks.learning --algo ppo --env treasure_hunt_v0 --seeds 0 1 2
    python -m benchmarks.learning --algo ddpg td3 sac ppo --env sbagents/SmartHome-v0 --seeds 0 1 2
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
from pathlib import Path
from typing import Any

from benchmarks.report import write_section
from sbagents.api import EvalOptions, ExecOptions, OutputOptions, Sb3Options, TrainSpec, train
from sbagents.core.run_dir import env_stem

RESULTS = Path(__file__).resolve().parent / "results"


def run_seed(algo: str, env: str, seed: int, episodes: int, log_folder: str, extra: dict[str, Any]) -> dict[str, Any]:
    """Train one seed with the shipped config; return its summary plus the machine load."""
    load_before = os.getloadavg()[0]
    result = train(TrainSpec(algo, env), OutputOptions(log_folder), EvalOptions(final_eval_episodes=episodes),
                   ExecOptions(seed=seed, verbose=0), sb3=Sb3Options(**extra))
    return {**result.summary, "load_before": round(load_before, 2), "load_after": round(os.getloadavg()[0], 2)}


def table(rows: list[dict[str, Any]]) -> str:
    """Markdown table of the runs."""
    metric_keys = sorted({k for r in rows for k in r["eval"]["metrics"]})
    head = ["algo", "env", "seed", "n_timesteps", "train s", "cpu s", "mean return", "success", *metric_keys, "load"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        ev = r["eval"]
        success = "-" if ev["success_rate"] is None else f"{ev['success_rate']:.2f}"
        metrics = [f"{ev['metrics'].get(k, float('nan')):.3f}" for k in metric_keys]
        cells = [r["algo"], r["env"], str(r["seed"]), str(r["n_timesteps"]), f"{r['train_seconds']:.1f}",
                 f"{r.get('train_cpu_seconds', float('nan')):.1f}", f"{ev['mean_return']:.1f}", success, *metrics,
                 f"{r['load_before']:.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--algo", nargs="+", required=True)
    parser.add_argument("--env", required=True)
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--episodes", type=int, default=100, help="greedy evaluation episodes per seed")
    parser.add_argument("--write", default="BENCHMARKS.md", help="Markdown file to update ('' to skip)")
    parser.add_argument("--vec-env", default=None, help="vec env type passed to train (default: train's)")
    args = parser.parse_args()
    extra = {"vec_env": args.vec_env} if args.vec_env else {}
    RESULTS.mkdir(exist_ok=True)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores")
    tables = []
    with tempfile.TemporaryDirectory() as logs:
        for algo in args.algo:
            rows = [run_seed(algo, args.env, s, args.episodes, logs, extra) for s in args.seeds]
            (RESULTS / f"learning_{env_stem(args.env)}_{algo}.json").write_text(json.dumps(rows, indent=2) + "\n")
            tables.append(table(rows))
            print(tables[-1], flush=True)
    command = f"python -m benchmarks.learning --algo {' '.join(args.algo)} --env {args.env} --seeds " + " ".join(
        map(str, args.seeds))
    text = f"## Learning: {args.env}\n\nCommand: `{command}` ({args.episodes} greedy evaluation episodes per seed, " \
        f"shipped zoo configs).\n\n" + "\n\n".join(tables)
    if args.write:
        write_section(args.write, text, f"learning-{env_stem(args.env)}-{'-'.join(args.algo)}")


if __name__ == "__main__":
    main()
