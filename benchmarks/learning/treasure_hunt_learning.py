"""TreasureHunt learning benchmark: parameter-shared PPO with the batched VecEnv and the shipped zoo config.

Per seed: train ``ppo`` on ``treasure_hunt_v0`` (``zoo_configs/ppo.yml``, optional ``--params`` overrides),
timing ``model.learn`` only, then evaluate the deterministic team on 100 seeded episodes
(:func:`sbagents.multiagent.team_eval.evaluate_team`, eval seed ``10000 + seed``) on the reference env.
Target: >= 4.5 of 5 treasures per episode on every seed in <= 90 s of training.

Two paths, same numbers: ``--via train`` runs :func:`sbagents.pipeline.training.train` with
``sb3=Sb3Options(vec_env="batched")`` (once the env factory supports it; the script checks the model really trained
on the batched env); ``--via direct`` builds the experiment from the zoo config and trains SB3 PPO on
:func:`sbagents.batched.make_batched_vec_env` itself; ``auto`` (default) picks ``train`` when available.

    python -m benchmarks.treasure_hunt_learning --seeds 0 1 2
    python -m benchmarks.treasure_hunt_learning --seeds 0 --params '{"n_envs": 16}'
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from typing import Any

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.utils import set_random_seed

from benchmarks.report import write_section
from sbagents.batched import BatchedTreasureHuntVecEnv, make_batched_vec_env
from sbagents.core.env_names import resolve_env
from sbagents.core.experiment import build_experiment
from sbagents.core.options import TrainSpec
from sbagents.envs.treasure_hunt_v0 import parallel_env
from sbagents.multiagent.team_eval import evaluate_team

ENV = "treasure_hunt_v0"


def train_supports_batched() -> bool:
    """Whether the env factory builds a batched VecEnv for ``sb3=Sb3Options(vec_env="batched")``."""
    try:
        from sbagents.env_factory import make_vec

        ref = resolve_env(ENV)
        probe = make_vec(build_experiment(TrainSpec("ppo", ENV), ref), ref, 1, None, vec_env="batched")
    except Exception:  # noqa: BLE001 - not wired yet (unknown vec_env) or any factory error
        return False
    probe.close()
    return isinstance(probe.unwrapped, BatchedTreasureHuntVecEnv)


def run_seed(seed: int, params: dict[str, Any], via: str, n_eval: int = 100) -> dict[str, Any]:
    """Train one seed and evaluate the deterministic team; returns a JSON-able dict."""
    torch.set_num_threads(1)
    ref = resolve_env(ENV)
    exp = build_experiment(TrainSpec("ppo", ENV, hyperparams=params), ref)
    if via == "train":
        from sbagents.api import EvalOptions, ExecOptions, OutputOptions, Sb3Options, train

        with tempfile.TemporaryDirectory() as logs:
            result = train(TrainSpec("ppo", ENV, hyperparams=params), OutputOptions(logs),
                           EvalOptions(eval_freq=-1, final_eval_episodes=0),
                           ExecOptions(seed=seed, verbose=0), sb3=Sb3Options(vec_env="batched"))
            model, train_s = result.model, float(result.summary["train_seconds"])
            if not isinstance(model.get_env().unwrapped, BatchedTreasureHuntVecEnv):  # type: ignore[union-attr]
                raise RuntimeError("train(sb3=Sb3Options(vec_env='batched')) did not use the batched VecEnv")
    else:
        set_random_seed(seed)
        vec = make_batched_vec_env(ENV, exp.n_envs, seed, exp.env_kwargs, None)
        model = PPO(exp.policy, vec, seed=seed, verbose=0, **exp.algo_kwargs)
        start = time.perf_counter()
        model.learn(exp.n_timesteps)
        train_s = time.perf_counter() - start
        vec.close()
    kwargs = dict(exp.env_kwargs)
    res = evaluate_team(model, lambda: parallel_env(**kwargs), n_episodes=n_eval, deterministic=True,
                        seed=10_000 + seed)
    return {
        "seed": seed,
        "via": via,
        "n_timesteps": exp.n_timesteps,
        "n_envs": exp.n_envs,
        "train_s": round(train_s, 1),
        "fps": round(exp.n_timesteps / train_s),
        "treasures": round(res["metrics"]["treasures_collected"], 3),
        "team_return": round(res["mean_return"], 2),
        "success_rate": round(res["success_rate"], 3),
        "load": round(os.getloadavg()[0], 2),
    }


def markdown(summary: dict[str, Any]) -> str:
    """A Markdown section with one row per seed (written between the learning markers of BENCHMARKS.md)."""
    lines = [
        "## TreasureHunt learning with the batched VecEnv",
        "",
        "Parameter-shared PPO, `zoo_configs/ppo.yml` entry `treasure_hunt_v0`"
        + (f" with overrides `{json.dumps(summary['params'])}`" if summary["params"] else "")
        + "; deterministic team evaluated on 100 episodes (eval seed 10000 + seed). Target: >= 4.5 treasures "
        "in <= 90 s of training. Command: `python -m benchmarks.treasure_hunt_learning --seeds 0 1 2`.",
        "",
        "| seed | path | n_envs | timesteps | train s | fps | treasures/episode | team return | success "
        "| load |",
        "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in summary["runs"]:
        lines.append(
            f"| {r['seed']} | {r['via']} | {r['n_envs']} | {r['n_timesteps']:,} | {r['train_s']} | "
            f"{r['fps']:,} | {r['treasures']} | {r['team_return']} | {r['success_rate']} | {r['load']} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--params", type=json.loads, default={}, help="JSON overrides of the zoo entry")
    parser.add_argument("--via", choices=("auto", "train", "direct"), default="auto")
    parser.add_argument("--json", default="benchmarks/results/treasure_hunt_learning.json")
    parser.add_argument("--output", default="BENCHMARKS.md", help="Markdown file to update ('' to skip)")
    args = parser.parse_args(argv)
    via = args.via if args.via != "auto" else ("train" if train_supports_batched() else "direct")
    runs = []
    for seed in args.seeds:
        row = run_seed(seed, args.params, via)
        print(json.dumps(row), flush=True)
        runs.append(row)
    summary = {
        "params": args.params,
        "runs": runs,
        "min_treasures": min(r["treasures"] for r in runs),
        "max_train_s": max(r["train_s"] for r in runs),
        "mean_train_s": round(float(np.mean([r["train_s"] for r in runs])), 1),
        "target_met": all(r["treasures"] >= 4.5 and r["train_s"] <= 90 for r in runs),
    }
    print(json.dumps({k: v for k, v in summary.items() if k != "runs"}))
    if args.json:
        os.makedirs(os.path.dirname(args.json) or ".", exist_ok=True)
        with open(args.json, "w") as fh:
            json.dump(summary, fh, indent=2)
    if args.output:
        write_section(args.output, markdown(summary), "treasure-hunt-learning")
    return summary


if __name__ == "__main__":
    main()
