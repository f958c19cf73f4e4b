"""Privacy-utility table: SmartHome DDPG trained with DP-SGD at several epsilons (delta 1e-5), beside no DP.

Each run is ``python -m sbagents.train --algo ddpg --env SmartHome-v0 --seed S [--dp-epsilon E] -params ...`` (the
same library call), evaluated by its final evaluation (``--episodes`` episodes, greedy): the share of steps that meet
the comfort criterion (``criterion_share``), the mean return, the training time and the epsilon the run spent.
The hyperparameters of every row are the shipped DDPG entry with the overrides of ``--params`` (the same for all
rows, epsilon = inf included, so the rows differ only in the noise).

    python -m benchmarks.private_learning --epsilons inf 8 3 1 --seeds 0 1 2 \\
        --params n_timesteps:20000 learning_starts:2000 batch_size:256 train_freq:4
"""

from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

from benchmarks.report import publish
from sbagents.api import EvalOptions, ExecOptions, OutputOptions, PrivacyOptions, TrainSpec, train
from sbagents.core.zoo_config import parse_overrides

RESULTS = Path(__file__).resolve().parent / "results"
SECTION = "private-smarthome"
ENV = "sbagents/SmartHome-v0"


def run(epsilon: float, seed: int, params: dict[str, Any], clip: float, episodes: int, logs: str) -> dict[str, Any]:
    """One run; epsilon = inf trains without DP."""
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


def markdown(result: dict[str, Any]) -> str:
    """The BENCHMARKS.md section."""
    params = " ".join(f"{k}:{v}" for k, v in result["params"].items())
    lines = ["## Private agents: SmartHome DDPG with DP-SGD", "",
             f"`python -m sbagents.train --algo ddpg --env SmartHome-v0 --seed S --dp-epsilon E --dp-clip "
             f"{result['clip']} -params {params}` (no `--dp-epsilon` for inf), delta 1e-5, unit of privacy: one "
             f"transition; final evaluation of {result['episodes']} greedy episodes. Command: `python -m "
             f"benchmarks.private_learning --epsilons {' '.join(str(e) for e in result['epsilons'])} --seeds "
             f"{' '.join(str(s) for s in result['seeds'])} --clip {result['clip']} --params {params}`.", "",
             "| epsilon (target) | seed | epsilon spent | noise multiplier | comfort criterion share | mean return | "
             "train s | load |", "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in result["runs"]:
        spent = "" if r["epsilon"] is None else f"{r['epsilon']:.2f}"
        noise = "" if r["noise_multiplier"] is None else f"{r['noise_multiplier']:.2f}"
        lines.append(f"| {r['epsilon_target']} | {r['seed']} | {spent} | {noise} | {100 * r['criterion_share']:.1f}% | "
                     f"{r['mean_return']:.1f} | {r['train_s']:.0f} | {r['load']} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.private_learning", description=__doc__)
    parser.add_argument("--epsilons", type=float, nargs="+", default=[math.inf, 8, 3, 1])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--clip", type=float, default=1.0)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--params", nargs="*", default=[], metavar="KEY:VALUE")
    parser.add_argument("--output", default="BENCHMARKS.md", help="Markdown file to update ('' = none)")
    parser.add_argument("--json", default=str(RESULTS / "private_smarthome.json"), help="raw results ('' = none)")
    args = parser.parse_args(argv)
    params = parse_overrides(args.params, "--params")
    runs = []
    with tempfile.TemporaryDirectory() as logs:
        for epsilon in args.epsilons:
            for seed in args.seeds:
                runs.append(run(epsilon, seed, params, args.clip, args.episodes, logs))
                print(json.dumps(runs[-1]), flush=True)
    result = {"epsilons": args.epsilons, "seeds": args.seeds, "clip": args.clip, "episodes": args.episodes,
              "params": params, "runs": runs}
    publish(markdown(result), result, args.output, args.json, SECTION)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
