"""Learning results with the shipped zoo configs: train on several seeds, evaluate the greedy policy.

Each run is exactly ``python -m sbagents.train --algo A --env E --seed S --final-eval-episodes N`` (the same
library call), so ``train_seconds`` is the wall time of ``model.learn`` and the evaluation is the run's
``summary.json``. One benchmark per env; its results file ``benchmarks/results/learning_<env>.json`` holds every
algorithm's runs and the per-seed statistics of their key metrics::

    python -m benchmarks run learning-smarthome --algo ddpg td3 sac ppo --seeds 0 1 2
    python -m benchmarks run learning-treasure-hunt-ppo --seeds 0 1 2
"""

from __future__ import annotations

import argparse
import os
import shlex
import tempfile
from collections.abc import Sequence
from functools import partial
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.learning.seed_table import StatRow, iqm_note, metric_stats, stats_table
from benchmarks.report import machine_info, recorded_argv

#: The env's key metric in ``eval.metrics`` (label, format); envs not listed have none beyond the return.
KEY_METRICS: dict[str, tuple[str, str, str]] = {
    "sbagents/SmartHome-v0": ("criterion_share", "comfort criterion share", ".3f"),
    "treasure_hunt_v0": ("treasures_collected", "treasures/episode", ".2f"),
}
#: A metric's earlier name in recorded files.
LEGACY_KEYS: dict[str, str] = {"treasures_collected": "treasures_per_episode"}


def run_seed(algo: str, env: str, seed: int, episodes: int, log_folder: str, extra: dict[str, Any],
             n_timesteps: int | None = None, eval_freq: int | None = None) -> dict[str, Any]:
    """Train one seed with the shipped config (``n_timesteps``: another budget; ``eval_freq``: another period of
    the periodic evaluations, -1 for none); return its summary plus the machine load."""
    from sbagents.api import EvalOptions, ExecOptions, OutputOptions, Sb3Options, TrainSpec, train

    load_before = os.getloadavg()[0]
    result = train(TrainSpec(algo, env, n_timesteps), OutputOptions(log_folder),
                   EvalOptions(eval_freq=eval_freq, final_eval_episodes=episodes), ExecOptions(seed=seed, verbose=0),
                   sb3=Sb3Options(**extra))
    return {**result.summary, "load_before": round(load_before, 2), "load_after": round(os.getloadavg()[0], 2)}


def key_metric(env: str, run: dict[str, Any]) -> float | None:
    """The env's key metric of one run (``None`` when the env has none or the run lacks it)."""
    if env not in KEY_METRICS:
        return None
    key = KEY_METRICS[env][0]
    metrics = run["eval"].get("metrics", {})
    value = metrics.get(key, metrics.get(LEGACY_KEYS.get(key, key)))  # files recorded before a key's rename
    return None if value is None else float(value)


def run_values(env: str, runs: list[dict[str, Any]]) -> dict[str, list[float]]:
    """Per-seed values of the metrics the statistics table shows: key metric, mean return, success, train s."""
    values: dict[str, list[float]] = {"mean_return": [float(r["eval"]["mean_return"]) for r in runs],
                                      "train_seconds": [float(r["train_seconds"]) for r in runs]}
    success = [r["eval"].get("success_rate") for r in runs]
    if all(s is not None for s in success):
        values["success_rate"] = [float(s) for s in success]
    key = [key_metric(env, r) for r in runs]
    if env in KEY_METRICS and all(v is not None for v in key):
        values[KEY_METRICS[env][0]] = [float(v) for v in key if v is not None]
    return values


def build_parser(name: str, algos: Sequence[str]) -> argparse.ArgumentParser:
    """The benchmark's options."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {name}",
                                     description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--algo", nargs="+", default=list(algos), help="algorithms (shipped zoo entries)")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--episodes", type=int, default=100, help="greedy evaluation episodes per seed")
    parser.add_argument("-n", "--n-timesteps", type=int, default=None, help="training budget (default: the config's)")
    parser.add_argument("--eval-freq", type=int, default=None,
                        help="env steps between periodic evaluations (default: train's; -1: none)")
    parser.add_argument("--vec-env", default=None, help="vec env type passed to train (default: train's)")
    return parser


def run_env(name: str, env: str, algos: Sequence[str], argv: Sequence[str]) -> dict[str, Any]:
    """Train and evaluate every algorithm and seed on ``env``; the results of benchmark ``name``."""
    args = build_parser(name, algos).parse_args(list(argv))
    extra = {"vec_env": args.vec_env} if args.vec_env else {}
    runs: dict[str, list[dict[str, Any]]] = {}
    with tempfile.TemporaryDirectory() as logs:
        for algo in args.algo:
            runs[algo] = [run_seed(algo, env, s, args.episodes, logs, extra, args.n_timesteps, args.eval_freq)
                          for s in args.seeds]
    return {
        "env": env, "algos": list(args.algo), "seeds": list(args.seeds), "episodes": args.episodes,
        "command": " ".join(["python -m benchmarks run", name, *map(shlex.quote, recorded_argv(list(argv)))]),
        "machine": machine_info(), "runs": runs,
        "stats": {algo: metric_stats(run_values(env, rows)) for algo, rows in runs.items()},
    }


def table(rows: list[dict[str, Any]]) -> str:
    """Markdown table of one algorithm's runs."""
    metric_keys = sorted({k for r in rows for k, v in r["eval"]["metrics"].items() if isinstance(v, int | float)})
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


def stat_rows(env: str, algo: str) -> list[StatRow]:
    """The statistics table's rows of one algorithm (keys ``algo/metric`` of :func:`flat_stats`)."""
    rows: list[StatRow] = []
    if env in KEY_METRICS:
        key, label, fmt = KEY_METRICS[env]
        rows.append((f"{algo}: {label}", f"{algo}/{key}", fmt))
    return rows + [(f"{algo}: mean return", f"{algo}/mean_return", ".1f"),
                   (f"{algo}: success", f"{algo}/success_rate", ".2f"),
                   (f"{algo}: train s", f"{algo}/train_seconds", ".1f")]


def machine_line(machine: dict[str, Any] | None) -> list[str]:
    """``Machine: ...`` of a run's :func:`benchmarks.report.machine_info` (nothing for results without it)."""
    if not machine:
        return []
    return ["", f"Machine: {machine['cpu']}, {machine['cores']} cores, torch {machine['torch']}, "
                f"SB3 {machine['stable_baselines3']}; run {machine['date']}."]


def render(results: dict[str, Any]) -> str:
    """The env's section: one table per algorithm, then the per-seed statistics of each."""
    env, runs = results["env"], results["runs"]
    flat = {f"{algo}/{key}": s for algo, by_key in results["stats"].items() for key, s in by_key.items()}
    rows = [row for algo in results["algos"] for row in stat_rows(env, algo)]
    n_seeds = len(results["seeds"])
    lines = [f"## Learning: {env}", "",
             f"Command: `{results['command']}` ({results['episodes']} greedy evaluation episodes per seed, "
             "shipped zoo configs).", *machine_line(results.get("machine")), ""]
    lines += ["\n\n".join(table(runs[algo]) for algo in results["algos"]), "", *stats_table(flat, rows), "",
              iqm_note(n_seeds)]
    return "\n".join(lines)


BENCHMARKS = (
    Benchmark(name="learning-smarthome", kind="learning", results="learning_sbagents_SmartHome-v0.json",
              summary="SmartHome-v0: DDPG / TD3 / SAC / PPO with the shipped zoo entries, 3 seeds, greedy comfort",
              run=partial(run_env, "learning-smarthome", "sbagents/SmartHome-v0", ("ddpg", "td3", "sac", "ppo")),
              render=render),
    Benchmark(name="learning-treasure-hunt-ppo", kind="learning", results="learning_treasure_hunt_v0.json",
              summary="treasure_hunt_v0: PPO with the shipped zoo entry through train, 3 seeds, treasures/episode",
              run=partial(run_env, "learning-treasure-hunt-ppo", "treasure_hunt_v0", ("ppo",)), render=render),
)
