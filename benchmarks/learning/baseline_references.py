"""The reference rows: random play and the scripted experts (``python -m sbagents.evaluate --policy random|scripted``)
on the book's envs, the teams and the games, each in a ``python -m sbagents.evaluate`` process of its own.

    python -m benchmarks run baseline-references [--episodes 100] [--kuka-episodes 50]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections.abc import Sequence
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.report import load_average, machine_info

NAME = "baseline-references"
#: (env, policies, whether it is a Kuka env: fewer episodes)
TASKS: tuple[tuple[str, tuple[str, ...], bool], ...] = (
    ("sbagents/GridWorld-v0", ("scripted", "random"), False),
    ("sbagents/HazardGridWorld-v0", ("scripted", "random"), False),
    ("sbagents/SmartHome-v0", ("scripted", "random"), False),
    ("sbagents/SmartHomePrefOnce-v0", ("scripted", "random"), False),
    ("sbagents/PickAndPlace-v0", ("scripted", "random"), True),
    ("sbagents/RobustPickAndPlace-v0", ("scripted", "random"), True),
    ("sbagents/KukaPickAndPlace-v0", ("scripted", "random"), True),
    ("sbagents/RobustKukaPickAndPlace-v0", ("scripted", "random"), True),
    ("treasure_hunt_v0", ("scripted", "random"), False),
    ("mpe2.simple_spread_v3", ("random",), False),
    ("pettingzoo.classic.rps_v2", ("random",), False),
    ("pettingzoo.classic.tictactoe_v3", ("scripted", "random"), False),
    ("pettingzoo.classic.connect_four_v3", ("scripted", "random"), False),
)


def build_parser() -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run baseline-references``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME}", description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=100, help="episodes (games) per row")
    parser.add_argument("--kuka-episodes", type=int, default=50, help="episodes per row on the Kuka envs")
    parser.add_argument("--quick", action="store_true", help="smoke run: 2 episodes per row")
    return parser


def _row(env: str, policy: str, episodes: int) -> dict[str, Any]:
    """``python -m sbagents.evaluate --policy POLICY --env ENV -n EPISODES --seed 0 --json``: the row."""
    start = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "sbagents.evaluate", "--policy", policy, "--env", env, "-n",
                          str(episodes), "--seed", "0", "--json"], check=True, capture_output=True, text=True,
                         env={**os.environ, "OMP_NUM_THREADS": "1"})
    summary: dict[str, Any] = json.loads(out.stdout.strip().splitlines()[-1])
    metrics = summary.get("metrics", {})
    seconds = round(time.perf_counter() - start, 1)
    return {"env": summary["env"], "policy": policy, "episodes": episodes, "seconds": seconds,
            "return": summary["mean_return"], "return_std": summary["std_return"],
            "success": summary.get("success_rate"), "cost": summary.get("mean_cost"),
            "length": summary["mean_length"], "win_rate": summary.get("win_rate"),
            "draw_rate": summary.get("draw_rate"), "loss_rate": summary.get("loss_rate"),
            "opponent": summary.get("opponent"), "note": summary.get("note"),
            "criterion_share": metrics.get("criterion_share"),
            "treasures": metrics.get("treasures_collected"), "landmarks": metrics.get("landmarks_covered")}


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Every (env, policy) row."""
    args = build_parser().parse_args(list(argv))
    episodes, kuka = (2, 2) if args.quick else (args.episodes, args.kuka_episodes)
    load_before = load_average()
    rows = []
    for env, policies, is_kuka in TASKS:
        for policy in policies:
            rows.append(_row(env, policy, kuka if is_kuka else episodes))
            print(f"{env} {policy}: {rows[-1]['return']:.2f}", file=sys.stderr)
    return {"command": f"python -m benchmarks run {NAME} --episodes {episodes} --kuka-episodes {kuka}",
            "machine": {**machine_info(), "load_before": load_before, "load_after": load_average()}, "rows": rows}


def _number(value: float | None, spec: str) -> str:
    return "" if value is None else format(value, spec)


def render(results: dict[str, Any]) -> str:
    """The section: one row per (env, policy)."""
    m = results["machine"]
    lines = [
        "## Baselines: random play and the scripted experts",
        "",
        f"Command: `{results['command']}`. Each row is `python -m sbagents.evaluate --policy POLICY --env ENV -n N "
        "--seed 0 --json` on the plain env (no wrappers, no normalization): `random` samples the action space "
        "(random legal moves in a game); `scripted` is the env's expert (`sbagents.registration.SCRIPTED_POLICIES`: "
        "GridWorld's shortest path, HazardGridWorld's shortest safe path, SmartHome's controller of the true state, "
        "the Kuka push and pick scripts, TreasureHunt's greedy team) or a game's strongest built-in player "
        "(minimax for tic-tac-toe, the heuristic for connect four), playing against random moves with the seats "
        "alternating. Nothing is trained, "
        "so there is no spread over training seeds: 1 seed of evaluation (episodes reset from seed 0); `+-` is the "
        "standard deviation over episodes. These are the "
        "reference rows beside the learned agents of the other sections, and what `python -m sbagents.collect "
        f"--policy scripted` records. {m['cpu']}, {m['cores']} cores, {m['date']}, load {m['load_before'][0]} before "
        f"/ {m['load_after'][0]} after.",
        "",
        "| env | policy | episodes | return | success | cost | length | other | s |",
        "|---|---|---:|---:|---:|---:|---:|---|---:|",
    ]
    for r in results["rows"]:
        other = []
        if r.get("win_rate") is not None:
            other.append(f"win / draw / loss {r['win_rate']:.2f} / {r['draw_rate']:.2f} / {r['loss_rate']:.2f} "
                         f"vs {r['opponent']}")
        for key, label in (("criterion_share", "comfort share"), ("treasures", "treasures"),
                           ("landmarks", "landmarks covered")):
            if r.get(key) is not None:
                other.append(f"{label} {r[key]:.3g}")
        if r.get("note"):
            other.append("zero-sum: the team return is 0 by construction")
        lines.append(f"| {r['env']} | {r['policy']} | {r['episodes']} | {r['return']:.2f} +- {r['return_std']:.2f} | "
                     f"{_number(r['success'], '.2f')} | {_number(r['cost'], '.2f')} | {r['length']:.1f} | "
                     f"{'; '.join(other)} | {r['seconds']:.1f} |")
    return "\n".join(lines)


BENCHMARKS = (
    Benchmark(name=NAME, kind="learning", results="baseline_references.json",
              summary="random play and the scripted experts on the book's envs, teams and games (reference rows)",
              run=run, render=render),
)
