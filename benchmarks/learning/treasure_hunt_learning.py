"""TreasureHunt learning benchmark: parameter-shared PPO with the batched VecEnv and the shipped zoo config.

Per seed: train ``ppo`` on ``treasure_hunt_v0`` (``zoo_configs/ppo.yml``, optional ``--params`` overrides),
timing ``model.learn`` only, then evaluate the deterministic team on 100 seeded episodes
(:func:`sbagents.multiagent.team_eval.evaluate_team`, eval seed ``10000 + seed``) on the reference env.
Target: >= 4.5 of 5 treasures per episode on every seed in <= 90 s of training.

Two paths, same numbers: ``--via train`` runs :func:`sbagents.pipeline.training.train` with
``sb3=Sb3Options(vec_env="batched")`` (once the env factory supports it; the script checks the model really trained
on the batched env); ``--via direct`` builds the experiment from the zoo config and trains SB3 PPO on
:func:`sbagents.batched.make_batched_vec_env` itself; ``auto`` (default) picks ``train`` when available.

    python -m benchmarks run treasure-hunt-learning --seeds 0 1 2
    python -m benchmarks run --output '' --results SCRATCH.json treasure-hunt-learning --seeds 0 \\
        --params '{"n_envs": 16}'
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import tempfile
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.utils import set_random_seed

from benchmarks.harness import Benchmark
from benchmarks.learning.seed_table import StatRow, iqm_note, metric_stats, stats_table
from benchmarks.report import machine_info, recorded_argv
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


def run_seed(seed: int, params: dict[str, Any], via: str, n_eval: int = 100,
             n_timesteps: int | None = None) -> dict[str, Any]:
    """Train one seed (``n_timesteps``: another budget than the config's) and evaluate the deterministic team;
    returns a JSON-able dict."""
    torch.set_num_threads(1)
    ref = resolve_env(ENV)
    spec = TrainSpec("ppo", ENV, n_timesteps, params)
    exp = build_experiment(spec, ref)
    if via == "train":
        from sbagents.api import EvalOptions, ExecOptions, OutputOptions, Sb3Options, train

        with tempfile.TemporaryDirectory() as logs:
            result = train(spec, OutputOptions(logs),
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


#: The statistics table's rows: label, key, format.
STAT_ROWS: tuple[StatRow, ...] = (("treasures/episode", "treasures", ".2f"), ("team return", "team_return", ".2f"),
                                  ("success", "success_rate", ".2f"), ("train s", "train_s", ".1f"))


def run_values(runs: list[dict[str, Any]]) -> dict[str, list[float]]:
    """Per-seed values of the statistics table's metrics."""
    return {key: [float(r[key]) for r in runs] for _, key, _ in STAT_ROWS}


def render(summary: dict[str, Any]) -> str:
    """The section: one row per seed, then the statistics over the seeds."""
    lines = [
        "## TreasureHunt learning with the batched VecEnv",
        "",
        "Parameter-shared PPO, `zoo_configs/ppo.yml` entry `treasure_hunt_v0`"
        + (f" with overrides `{json.dumps(summary['params'])}`" if summary["params"] else "")
        + f"; deterministic team evaluated on {summary.get('n_eval', 100)} episodes (eval seed 10000 + seed). "
        f"Target: >= 4.5 treasures in <= 90 s of training. Command: `{summary['command']}`.",
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
    met = "met" if summary["target_met"] else "not met"
    lines += ["", *stats_table(summary["stats"], STAT_ROWS), "", f"Target {met}. " + iqm_note(len(summary["runs"]))]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """The benchmark's options."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks run treasure-hunt-learning",
                                     description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--params", type=json.loads, default={}, help="JSON overrides of the zoo entry")
    parser.add_argument("--via", choices=("auto", "train", "direct"), default="auto")
    parser.add_argument("-n", "--n-timesteps", type=int, default=None, help="training budget (default: the config's)")
    parser.add_argument("--n-eval", type=int, default=100, help="evaluation episodes per seed")
    return parser


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Train and evaluate every seed; the results (runs, target, statistics over the seeds)."""
    args = build_parser().parse_args(list(argv))
    via = args.via if args.via != "auto" else ("train" if train_supports_batched() else "direct")
    runs = []
    for seed in args.seeds:
        row = run_seed(seed, args.params, via, args.n_eval, args.n_timesteps)
        print(json.dumps(row), flush=True)
        runs.append(row)
    return {
        "params": args.params,
        "n_eval": args.n_eval,
        "runs": runs,
        "min_treasures": min(r["treasures"] for r in runs),
        "max_train_s": max(r["train_s"] for r in runs),
        "mean_train_s": round(float(np.mean([r["train_s"] for r in runs])), 1),
        "target_met": all(r["treasures"] >= 4.5 and r["train_s"] <= 90 for r in runs),
        "command": " ".join(["python -m benchmarks run treasure-hunt-learning",
                             *map(shlex.quote, recorded_argv(list(argv)))]),
        "machine": machine_info(),
        "stats": metric_stats(run_values(runs)),
    }


BENCHMARKS = (
    Benchmark(name="treasure-hunt-learning", kind="learning", results="treasure_hunt_learning.json",
              summary="treasure_hunt_v0: parameter-shared PPO on the batched VecEnv, 3 seeds, target >= 4.5 in 90 s",
              run=run, render=render),
)
