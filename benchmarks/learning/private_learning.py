"""Privacy-utility table: SmartHome DDPG trained with DP-SGD at several epsilons (delta 1e-5), beside no DP.

Each run is ``python -m sbagents.train --algo ddpg --env SmartHome-v0 --seed S [--dp-epsilon E] -params ...`` (the
same library call), evaluated by its final evaluation (``--episodes`` episodes, greedy): the share of steps that meet
the comfort criterion (``criterion_share``), the mean return, the training time and the epsilon the run spent.
The hyperparameters of every row are the shipped DDPG entry with the overrides of ``--params`` (the same for all
rows, epsilon = inf included, so the rows differ only in the noise).

    python -m benchmarks run private-smarthome --epsilons inf 8 3 1 --seeds 0 1 2 \\
        --params n_timesteps:20000 learning_starts:2000 batch_size:256 train_freq:4
"""

from __future__ import annotations

import argparse
import math
import os
import shlex
import tempfile
from collections.abc import Sequence
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.learning.seed_table import StatsRow, grouped_stats_table, stats_of
from benchmarks.report import recorded_argv

SECTION = "private-smarthome"
ENV = "sbagents/SmartHome-v0"


def run_one(epsilon: float, seed: int, params: dict[str, Any], clip: float, episodes: int,
            logs: str) -> dict[str, Any]:
    """One run; epsilon = inf trains without DP."""
    from sbagents.api import EvalOptions, ExecOptions, OutputOptions, PrivacyOptions, TrainSpec, train

    privacy = PrivacyOptions(epsilon=None if math.isinf(epsilon) else epsilon, clip=clip)
    load = os.getloadavg()[0]
    result = train(TrainSpec("ddpg", ENV, hyperparams=params), OutputOptions(logs),
                   EvalOptions(eval_freq=0, final_eval_episodes=episodes), ExecOptions(seed=seed, verbose=0),
                   features=[privacy])
    ev, dp = result.summary["eval"], result.summary.get("dp", {})
    return {"epsilon_target": epsilon, "seed": seed, "epsilon": dp.get("epsilon"),
            "noise_multiplier": dp.get("noise_multiplier"), "n_timesteps": result.summary["n_timesteps"],
            "train_s": result.summary["train_seconds"], "criterion_share": ev["metrics"]["criterion_share"],
            "mean_return": ev["mean_return"], "load": round(load, 2)}


def add_stats(result: dict[str, Any]) -> dict[str, Any]:
    """``result`` with ``stats[str(epsilon)]``: the comfort share (%) and mean return over seeds."""
    stats: dict[str, Any] = {}
    for epsilon in result["epsilons"]:
        runs = [r for r in result["runs"] if r["epsilon_target"] == epsilon]
        stats[str(epsilon)] = {"comfort_pct": stats_of([100 * r["criterion_share"] for r in runs]),
                               "mean_return": stats_of([r["mean_return"] for r in runs])}
    return {**result, "stats": stats}


def markdown(result: dict[str, Any]) -> str:
    """The BENCHMARKS.md section."""
    params = " ".join(f"{k}:{v}" for k, v in result["params"].items())
    lines = ["## Private agents: SmartHome DDPG with DP-SGD", "",
             f"`python -m sbagents.train --algo ddpg --env SmartHome-v0 --seed S --dp-epsilon E --dp-clip "
             f"{result['clip']} -params {params}` (no `--dp-epsilon` for inf), delta 1e-5, unit of privacy: one "
             f"transition; final evaluation of {result['episodes']} greedy episodes. Command: "
             f"`{result['command']}`.", "",
             "| epsilon (target) | seed | epsilon spent | noise multiplier | comfort criterion share | mean return | "
             "train s | load |", "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in result["runs"]:
        spent = "" if r["epsilon"] is None else f"{r['epsilon']:.2f}"
        noise = "" if r["noise_multiplier"] is None else f"{r['noise_multiplier']:.2f}"
        lines.append(f"| {r['epsilon_target']} | {r['seed']} | {spent} | {noise} | {100 * r['criterion_share']:.1f}% | "
                     f"{r['mean_return']:.1f} | {r['train_s']:.0f} | {r['load']} |")
    rows: list[StatsRow] = []
    for epsilon, stats in result["stats"].items():
        rows += [(f"epsilon {epsilon}", "comfort share (%)", stats["comfort_pct"], ".1f"),
                 (f"epsilon {epsilon}", "mean return", stats["mean_return"], ".1f")]
    return "\n".join([*lines, "", *grouped_stats_table("epsilon (target)", rows)])


def build_parser() -> argparse.ArgumentParser:
    """The benchmark's options."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}", description=__doc__)
    parser.add_argument("--epsilons", type=float, nargs="+", default=[math.inf, 8, 3, 1])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--clip", type=float, default=1.0)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--params", nargs="*", default=[], metavar="KEY:VALUE")
    return parser


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Train and evaluate every (epsilon, seed); the results of the section."""
    from sbagents.core.zoo_config import parse_overrides

    args = build_parser().parse_args(list(argv))
    params = parse_overrides(args.params, "--params")
    runs = []
    with tempfile.TemporaryDirectory() as logs:
        for epsilon in args.epsilons:
            for seed in args.seeds:
                runs.append(run_one(epsilon, seed, params, args.clip, args.episodes, logs))
                print(runs[-1], flush=True)
    command = shlex.join(["python", "-m", "benchmarks", "run", SECTION, *recorded_argv(list(argv))])
    return add_stats({"command": command, "epsilons": args.epsilons, "seeds": args.seeds, "clip": args.clip,
                      "episodes": args.episodes, "params": params, "runs": runs})


BENCHMARKS = (
    Benchmark(name=SECTION, kind="learning", results="private_smarthome.json",
              summary="SmartHome DDPG with DP-SGD at several epsilons: comfort share and return over seeds",
              run=run, render=markdown),
)
