"""Listing many runs in the dashboard: ``/api/runs`` over N generated run dirs, cold and warm.

Generates N SmartHome-like run dirs (``summary.json``, ``args.yml``, ``config.yml``, ``command.txt``, a monitor file
of 1,000 episodes, ``evaluations.npz``), then, through the Flask app's test client in this process: the first
listing (every run read: the baseline), the next listings (rows cached, each run dir only ``stat``-ed; median of 5),
and a listing after one run's files changed (that run re-read).

    python -m benchmarks run dashboard-runs [--runs 200]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import Benchmark
from benchmarks.report import machine_info, recorded_argv

SECTION = "dashboard-runs"


def generate(folder: Path, n_runs: int, episodes: int = 1000) -> None:
    """``n_runs`` run dirs under ``folder/<algo>/sbagents_SmartHome-v0_<k>/``."""
    monitor = "\n".join(f"{-100 + i * 0.05:.3f},100,{i * 0.8:.2f}" for i in range(episodes))
    for i in range(n_runs):
        algo = ("ddpg", "td3", "sac", "ppo")[i % 4]
        run_dir = folder / algo / f"sbagents_SmartHome-v0_{i // 4 + 1}"
        (run_dir / "sbagents_SmartHome-v0").mkdir(parents=True)
        (run_dir / "sbagents_SmartHome-v0" / "args.yml").write_text(
            f"algo: {algo}\nenv: sbagents/SmartHome-v0\nseed: {i}\nn_timesteps: 100000\neval_freq: 10000\n")
        (run_dir / "sbagents_SmartHome-v0" / "config.yml").write_text("policy: MlpPolicy\nlearning_rate: 0.001\n")
        (run_dir / "command.txt").write_text(f"python -m sbagents.train --algo {algo} --env SmartHome-v0\n")
        (run_dir / "summary.json").write_text(json.dumps({
            "algo": algo, "env": "sbagents/SmartHome-v0", "seed": i, "n_timesteps": 100_000, "train_seconds": 800.0,
            "fps": 125.0, "interrupted": False, "eval": {"mean_return": -20.0, "std_return": 3.0, "success_rate": 1.0},
        }))
        (run_dir / "0.monitor.csv").write_text('#{"t_start": 1000.0}\nr,l,t\n' + monitor + "\n")
        np.savez(run_dir / "evaluations.npz", timesteps=np.arange(1, 11) * 10_000, results=np.zeros((10, 5)))


def measure(n_runs: int = 200) -> dict[str, Any]:
    """Time ``/api/runs`` over ``n_runs`` generated run dirs: first listing, next ones (median of 5), one changed."""
    from sbagents.dashboard.app import create_app
    from sbagents.dashboard.folders import ServedFolders

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "logs"
        generate(folder, n_runs)
        client = create_app(ServedFolders.from_paths([folder])).test_client()

        def listing() -> tuple[float, int]:
            start = time.perf_counter()
            response = client.get("/api/runs")
            elapsed = time.perf_counter() - start
            assert response.status_code == 200
            return elapsed, len(response.get_json()["runs"])

        cold, listed = listing()
        warm = statistics.median(listing()[0] for _ in range(5))
        touched = folder / "ddpg" / "sbagents_SmartHome-v0_1" / "summary.json"
        touched.write_text(touched.read_text().replace('"fps": 125.0', '"fps": 126.0'))
        one_changed, _ = listing()
    return {"machine": machine_info(), "runs": n_runs, "listed": listed, "cold_s": cold, "warm_s": warm,
            "one_changed_s": one_changed, "cold_over_warm": cold / warm}


def markdown(result: dict[str, Any]) -> str:
    """The ``dashboard-runs`` section, from the results alone."""
    m, command = result["machine"], result["command"]
    return "\n".join([
        "## Dashboard: listing runs", "",
        f"Machine: {m.get('cpu', '?')}, {m.get('cores', '?')} cores, Python {m.get('python', '?')}; "
        f"{m.get('date', '')}. Command: `{command}`.", "",
        f"{result['runs']} generated SmartHome run dirs (summary, args, config, command, a 1,000-episode monitor file, "
        "evaluations), listed by `/api/runs` through the app's test client (what the runs page polls every 3 s).", "",
        "| listing | time |", "|---|---:|",
        f"| first (every run read; the baseline) | {1000 * result['cold_s']:.1f} ms |",
        f"| next ones (rows cached, run dirs stat-ed; median of 5) | {1000 * result['warm_s']:.1f} ms "
        f"({result['cold_over_warm']:.1f}x faster) |",
        f"| after one run's summary.json changed | {1000 * result['one_changed_s']:.1f} ms |",
    ])


def run(argv: Sequence[str]) -> dict[str, Any]:
    """``python -m benchmarks run dashboard-runs [--runs N]``: measure; the results record the command."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=200, help="run dirs to generate")
    args = parser.parse_args(list(argv))
    result = measure(args.runs)
    result["command"] = " ".join(["python -m benchmarks run", SECTION, *recorded_argv(list(argv))])
    return result


BENCHMARKS = (
    Benchmark(name=SECTION, kind="speed", results="dashboard_runs.json",
              summary="dashboard /api/runs over 200 generated run dirs: first listing vs cached ones",
              run=run, render=markdown),
)
