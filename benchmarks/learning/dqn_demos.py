"""DQN from demonstrations: demonstration replay alone and with DQfD's margin loss, beside plain DQN, on the book's
grid worlds at budgets where plain DQN has not yet learned.

Per env and seed: ``python -m sbagents.collect --policy scripted`` records 10 expert episodes (reset seeds from
``1000 * seed``); then ``dqn`` trains with the env's zoo entry for ``--steps`` env steps in three variants: ``none``,
``replay`` (``--demos DATASET``: a quarter of every batch from the demonstrations) and ``margin`` (``--demos DATASET
--demo-bc 1``: plus DQfD's large-margin loss), and plays 20 greedy episodes at the end. No pretraining: what the
demonstrations do during learning is measured::

    python -m benchmarks run dqn-demos [--seeds 0 1 2] [--steps 2000 5000]
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
from benchmarks.stats import IQM_NOTE, format_iqm, seed_stats

NAME = "dqn-demos"
ENVS = ("sbagents/GridWorld-v0", "sbagents/HazardGridWorld-v0")
VARIANTS: dict[str, tuple[str, ...]] = {"none": (), "replay": ("--demos", "{dataset}"),
                                         "margin": ("--demos", "{dataset}", "--demo-bc", "1")}
EPISODES, EVAL_EPISODES = 10, 20


def build_parser() -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run dqn-demos``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME}", description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--steps", type=int, nargs="+", default=[2000, 5000], help="env steps of each run")
    parser.add_argument("--quick", action="store_true", help="smoke run: one seed, 600 steps")
    return parser


def _one(env_id: str, variant: str, seed: int, steps: int, dataset: str, work: Path, env: dict[str, str]
         ) -> dict[str, Any]:
    logs = work / f"{env_id.split('/')[-1]}_{variant}_{seed}_{steps}"
    flags = [f.format(dataset=dataset) for f in VARIANTS[variant]]
    run_module("sbagents.train", "--algo", "dqn", "--env", env_id, *flags, "--seed", str(seed), "-n", str(steps), "-f",
               str(logs), "--eval-freq", "-1", "--final-eval-episodes", str(EVAL_EPISODES), "--verbose", "0", env=env)
    (summary_file,) = logs.rglob("summary.json")
    summary = json.loads(summary_file.read_text())
    return {"env": env_id, "variant": variant, "seed": seed, "steps": steps,
            "return": float(summary["eval"]["mean_return"]), "success": summary["eval"].get("success_rate"),
            "train_s": float(summary["train_seconds"])}


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Every (env, budget, variant, seed) row and per-cell statistics of the greedy return."""
    args = build_parser().parse_args(list(argv))
    if args.quick:
        args.seeds, args.steps = args.seeds[:1], [600]
    work = Path(tempfile.mkdtemp(prefix=f"{NAME}-"))
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MINARI_DATASETS_PATH": str(work / "datasets")}
    load_before = load_average()
    rows = []
    for env_id in ENVS:
        for seed in args.seeds:
            dataset = f"bench/{env_id.split('/')[-1].lower()}-expert-s{seed}-v0"
            run_module("sbagents.collect", "--env", env_id, "--policy", "scripted", "--episodes", str(EPISODES),
                       "--dataset", dataset, "--seed", str(1000 * seed), "--ref-episodes", "0", env=env)
            for steps in args.steps:
                for variant in VARIANTS:
                    rows.append(_one(env_id, variant, seed, steps, dataset, work, env))
                    print(f"{env_id} {steps} {variant} seed {seed}: {rows[-1]['return']:.1f}", file=sys.stderr)
    stats = {f"{e}|{n}|{v}": seed_stats([r["return"] for r in rows
                                         if (r["env"], r["steps"], r["variant"]) == (e, n, v)])
             for e in ENVS for n in args.steps for v in VARIANTS}
    return {"command": f"python -m benchmarks run {NAME} --seeds {' '.join(map(str, args.seeds))} --steps "
                       f"{' '.join(map(str, args.steps))}",
            "machine": {**machine_info(), "load_before": load_before, "load_after": load_average()},
            "rows": rows, "stats": stats}


def render(results: dict[str, Any]) -> str:
    """The section: the greedy return per env, budget and variant over seeds."""
    m = results["machine"]
    lines = [
        "## DQN from demonstrations: demonstration replay and DQfD's margin loss",
        "",
        f"Command: `{results['command']}`. Per env and seed, {EPISODES} episodes of the scripted expert (its shortest "
        "(safe) path); `dqn` with the env's zoo entry and no pretraining: `none`, `replay` (`--demos DATASET`, a "
        "quarter of every batch from the demonstrations) and `margin` (`--demos DATASET --demo-bc 1`, plus DQfD's "
        f"large-margin loss, margin 0.8); {EVAL_EPISODES} greedy episodes at the end. GridWorld's optimum is 93, "
        f"HazardGridWorld's safe optimum 87. {m['cpu']}, {m['cores']} cores, {m['date']}.",
        "",
        "| env | steps | variant | greedy return per seed | IQM [95% CI] | success |",
        "|---|---:|---|---|---|---|",
    ]
    for key, st in results["stats"].items():
        env_id, steps, variant = key.split("|")
        cell = [r for r in results["rows"] if (r["env"], str(r["steps"]), r["variant"]) == (env_id, steps, variant)]
        per_seed = ", ".join(f"{r['return']:.1f}" for r in cell)
        success = ", ".join("-" if r["success"] is None else f"{r['success']:.2f}" for r in cell)
        lines.append(f"| {env_id} | {int(steps):,} | {variant} | {per_seed} | {format_iqm(st, '.1f')} | {success} |")
    lines += ["", IQM_NOTE]
    return "\n".join(lines)


BENCHMARKS = (
    Benchmark(name=NAME, kind="learning", results="dqn_demos.json",
              summary="DQN with demonstration replay and DQfD's margin loss vs plain DQN on the grid worlds",
              run=run, render=render),
)
