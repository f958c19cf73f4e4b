"""The main job, ``python -m sbagents.train`` with no options (tabular Q-learning on GridWorld), over seeds.

Each seed runs the CLI's default training (20,000 steps) in this process and reads its ``summary.json``: the greedy
return of the evaluation (93 is the optimum: the 8-step path), the success rate and the training time.

    python -m benchmarks run gridworld-default [--seeds 0 1 2 3 4]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.report import load_average, machine_info
from benchmarks.stats import format_iqm, format_mean_std, seed_stats

NAME = "gridworld-default"
OPTIMUM = 93.0


def build_parser() -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run gridworld-default``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME}", description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="training seeds")
    return parser


def train_default(seed: int, folder: Path) -> dict[str, Any]:
    """One default training (``python -m sbagents.train -f folder --seed seed`` in-process): its summary."""
    import contextlib
    import io

    from sbagents.train import main

    with contextlib.redirect_stdout(io.StringIO()):
        main(["-f", str(folder), "--seed", str(seed)])
    (summary,) = folder.rglob("summary.json")
    result: dict[str, Any] = json.loads(summary.read_text())
    return result


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Train the default run once per seed; the per-seed returns, success and times with their statistics."""
    import torch

    args = build_parser().parse_args(list(argv))
    torch.set_num_threads(1)
    load_before = load_average()
    runs = []
    for seed in args.seeds:
        with tempfile.TemporaryDirectory() as tmp:
            s = train_default(seed, Path(tmp))
        runs.append({"seed": seed, "return": s["eval"]["mean_return"], "success": s["eval"]["success_rate"],
                     "train_seconds": s["train_seconds"], "train_cpu_seconds": s["train_cpu_seconds"],
                     "n_timesteps": s["n_timesteps"]})
    seeds = " ".join(str(s) for s in args.seeds)
    return {
        "command": f"python -m benchmarks run {NAME} --seeds {seeds}",
        "machine": {**machine_info(), "load_before": load_before, "load_after": load_average()},
        "runs": runs,
        "stats": {"return": seed_stats([r["return"] for r in runs]),
                  "train_seconds": seed_stats([r["train_seconds"] for r in runs], higher_is_better=False)},
    }


def render(results: dict[str, Any]) -> str:
    """The section: one row per seed, then mean +- std and IQM [95% CI] of the return and the training time."""
    m, runs, stats = results["machine"], results["runs"], results["stats"]
    lines = [
        "## GridWorld: the default `python -m sbagents.train`",
        "",
        f"Command: `{results['command']}` (each seed is `python -m sbagents.train --seed SEED`: tabular Q-learning, "
        f"{runs[0]['n_timesteps']:,} steps, greedy evaluation over 10 episodes; {OPTIMUM:.0f} is the optimum). "
        f"{m['cpu']}, {m['cores']} cores, {m['date']}, load {m['load_before'][0]} before / "
        f"{m['load_after'][0]} after.",
        "",
        "| seed | return | success | train s | train cpu s |",
        "|---:|---:|---:|---:|---:|",
    ]
    lines += [f"| {r['seed']} | {r['return']:.1f} | {r['success']:.2f} | {r['train_seconds']:.2f} | "
              f"{r['train_cpu_seconds']:.2f} |" for r in runs]
    ret, secs = stats["return"], stats["train_seconds"]
    lines += [
        "",
        f"Over {ret['n']} seeds: return {format_mean_std(ret, '.1f')} (mean +- std), IQM {format_iqm(ret, '.1f')}; "
        f"train seconds {format_mean_std(secs)}, IQM {format_iqm(secs)}. IQM: the interquartile mean; brackets: its "
        "95% stratified bootstrap interval (rliable).",
    ]
    return "\n".join(lines)


BENCHMARKS = (
    Benchmark(name=NAME, kind="learning", results="gridworld_default.json",
              summary="the main job (python -m sbagents.train, tabular Q-learning on GridWorld) over seeds",
              run=run, render=render),
)
