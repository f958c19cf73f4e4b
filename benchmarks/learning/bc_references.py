"""Behaviour cloning alone: a policy cloned from the scripted expert's dataset (``train --pretrain``), evaluated with
no reinforcement learning step, beside the expert and random play.

For each env and seed: ``python -m sbagents.collect --policy scripted`` records the expert's episodes (reset seeds
from ``1000 * seed``), then ``python -m sbagents.train --algo ALGO --pretrain DATASET`` clones them into a new model
whose learning never starts (an off-policy algorithm with ``learning_starts`` above the budget: its weights stay the
clone's), and its final evaluation plays the clone greedily. The score is also given normalized the way Minari
normalizes one: ``(return - random) / (expert - random)``, with the expert's and random play's mean returns of the
same evaluation episodes.

    python -m benchmarks run bc-references [--seeds 0 1 2] [--episodes 20]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.report import load_average, machine_info, run_module
from benchmarks.stats import IQM_NOTE, format_iqm, format_mean_std, seed_stats

NAME = "bc-references"
#: (env, algorithm that clones it with no learning step)
TASKS: tuple[tuple[str, str], ...] = (("sbagents/GridWorld-v0", "dqn"), ("sbagents/SmartHome-v0", "td3"))
EVAL_EPISODES = 100


def build_parser() -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run bc-references``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME}", description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="seeds (dataset, clone, evaluation)")
    parser.add_argument("--episodes", type=int, default=20, help="expert episodes per dataset")
    parser.add_argument("--quick", action="store_true", help="smoke run: one seed, 2 episodes")
    return parser


def _evaluate(env_id: str, policy: str, seed: int, env: dict[str, str]) -> float:
    out = run_module("sbagents.evaluate", "--policy", policy, "--env", env_id, "-n", str(EVAL_EPISODES), "--seed",
                     str(seed), "--json", env=env)
    return float(json.loads(out.strip().splitlines()[-1])["mean_return"])


def _one(env_id: str, algo: str, seed: int, episodes: int, work: Path) -> dict[str, Any]:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MINARI_DATASETS_PATH": str(work / "datasets")}
    dataset = f"bench/{env_id.split('/')[-1].lower()}-expert-s{seed}-v0"
    run_module("sbagents.collect", "--env", env_id, "--policy", "scripted", "--episodes", str(episodes),
               "--dataset", dataset, "--seed", str(1000 * seed), "--ref-episodes", "0", env=env)
    logs = work / f"logs_{env_id.split('/')[-1]}_{seed}"
    run_module("sbagents.train", "--algo", algo, "--env", env_id, "--pretrain", dataset, "--seed", str(seed), "-n",
               "100", "-f", str(logs), "--eval-freq", "-1", "--final-eval-episodes", str(EVAL_EPISODES), "--verbose",
               "0", "-params", "learning_starts:1000", env=env)
    (summary_file,) = logs.rglob("summary.json")
    summary = json.loads(summary_file.read_text())
    item = summary["pretrain"]
    # the final evaluation resets from the run's seed: the expert and random play are scored on the same resets
    expert, random = _evaluate(env_id, "scripted", seed, env), _evaluate(env_id, "random", seed, env)
    clone = float(summary["eval"]["mean_return"])
    return {"env": env_id, "algo": algo, "seed": seed, "pairs": item["n_train"] + item["n_holdout"],
            "holdout_loss": item["holdout_loss"], "clone": clone, "expert": expert, "random": random,
            "normalized": (clone - random) / (expert - random), "success": summary["eval"].get("success_rate")}


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Every (env, seed) row and per-env statistics of the normalized score."""
    args = build_parser().parse_args(list(argv))
    if args.quick:
        args.seeds, args.episodes = args.seeds[:1], 2
    work = Path(tempfile.mkdtemp(prefix="bc-references-"))
    load_before = load_average()
    rows = []
    for env_id, algo in TASKS:
        for seed in args.seeds:
            rows.append(_one(env_id, algo, seed, args.episodes, work))
            print(f"{env_id} seed {seed}: clone {rows[-1]['clone']:.2f}, expert {rows[-1]['expert']:.2f}",
                  file=sys.stderr)
    stats = {env_id: seed_stats([r["normalized"] for r in rows if r["env"] == env_id]) for env_id, _ in TASKS}
    seeds = " ".join(str(s) for s in args.seeds)
    return {"command": f"python -m benchmarks run {NAME} --seeds {seeds} --episodes {args.episodes}",
            "episodes": args.episodes,
            "machine": {**machine_info(), "load_before": load_before, "load_after": load_average()},
            "rows": rows, "stats": stats}


def render(results: dict[str, Any]) -> str:
    """The section: one row per (env, seed), then the normalized score over seeds."""
    m = results["machine"]
    lines = [
        "## Behaviour cloning alone: clones of the scripted experts",
        "",
        f"Command: `{results['command']}`. Per env and seed: `python -m sbagents.collect --policy scripted` records "
        f"{results['episodes']} expert episodes, `python -m sbagents.train --algo ALGO --pretrain DATASET` clones "
        "them (2,000 steps of batches of 256, the default) into a model that then takes no learning step (off-policy, "
        "`learning_starts` above its 100-step budget), and the run's final evaluation plays the clone greedily over "
        f"{EVAL_EPISODES} episodes; the expert and random play are scored on the same resets. Normalized: "
        "(clone - random) / (expert - random), Minari's normalized score. "
        f"{m['cpu']}, {m['cores']} cores, {m['date']}, load {m['load_before'][0]} before / {m['load_after'][0]} after.",
        "",
        "| env | algo | seed | pairs | held-out loss | clone | expert | random | normalized | success |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results["rows"]:
        success = "" if r["success"] is None else f"{r['success']:.2f}"
        lines.append(f"| {r['env']} | {r['algo']} | {r['seed']} | {r['pairs']:,} | {r['holdout_loss']:.3g} | "
                     f"{r['clone']:.2f} | {r['expert']:.2f} | {r['random']:.2f} | {r['normalized']:.3f} | "
                     f"{success} |")
    lines.append("")
    for env_id, st in results["stats"].items():
        lines.append(f"- {env_id}: normalized score {format_mean_std(st, '.3f')} (mean +- std over {st['n']} seeds), "
                     f"IQM {format_iqm(st, '.3f')}; target >= 0.95.")
    lines += ["", IQM_NOTE]
    return "\n".join(lines)


BENCHMARKS = (
    Benchmark(name=NAME, kind="learning", results="bc_references.json",
              summary="behaviour cloning alone from the scripted experts' datasets (GridWorld, SmartHome), over seeds",
              run=run, render=render),
)
