"""Hyperparameter / observation search for parameter-shared SB3 agents on ``treasure_hunt_v0``.

One run = train ``algo`` with the given hyperparameters for ``n_timesteps`` env (agent) steps, measure the
wall time of ``model.learn`` only, then evaluate the deterministic team on 100 seeded episodes
(:func:`sbagents.multiagent.team_eval.evaluate_team`). Prints one JSON line per seed and a summary line.

Example (the final PPO config)::

    python benchmarks/treasure_hunt_search.py --algo ppo --seeds 0 1 2 --n-timesteps 150000 \\
        --params '{"n_envs": 8, "n_steps": 64, "batch_size": 256, "n_epochs": 4, "learning_rate": 0.001}'

``--params`` is a JSON mapping with ``n_envs``, ``net_arch``, ``activation_fn`` (``tanh``/``relu``) and the
algorithm's constructor kwargs; ``--env-kwargs`` a JSON mapping for ``parallel_env``.
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import numpy as np
import torch
from stable_baselines3 import DQN, PPO

from sbagents.envs.treasure_hunt_v0 import parallel_env
from sbagents.multiagent.parameter_sharing import make_parameter_sharing_vec_env
from sbagents.multiagent.team_eval import evaluate_team

ALGOS: dict[str, Any] = {"ppo": PPO, "dqn": DQN}
ACTIVATIONS = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}


def _linear(initial: float) -> Any:
    return lambda progress_remaining: progress_remaining * initial


def run(
    algo: str,
    params: dict[str, Any],
    env_kwargs: dict[str, Any],
    n_timesteps: int,
    seed: int,
    n_eval: int = 100,
) -> dict[str, Any]:
    """Train one seed and evaluate it; returns a JSON-able dict with time and team metrics."""
    torch.set_num_threads(1)
    params = dict(params)
    n_envs = int(params.pop("n_envs", 8))
    policy_kwargs = {
        "net_arch": params.pop("net_arch", [64, 64]),
        "activation_fn": ACTIVATIONS[params.pop("activation_fn", "tanh")],
    }
    for key in ("learning_rate", "clip_range"):
        value = params.get(key)
        if isinstance(value, str) and value.startswith("lin_"):  # RL Zoo style linear schedule
            params[key] = _linear(float(value[4:]))
    vec = make_parameter_sharing_vec_env(parallel_env, n_envs=n_envs, seed=seed, env_kwargs=env_kwargs)
    model = ALGOS[algo]("MlpPolicy", vec, policy_kwargs=policy_kwargs, seed=seed, verbose=0, **params)
    start = time.perf_counter()
    model.learn(total_timesteps=n_timesteps)
    train_s = time.perf_counter() - start
    result = evaluate_team(model, lambda: parallel_env(**env_kwargs), n_episodes=n_eval, seed=10_000 + seed)
    return {
        "algo": algo,
        "seed": seed,
        "n_timesteps": n_timesteps,
        "train_s": round(train_s, 1),
        "fps": round(n_timesteps / train_s),
        "treasures": round(result["metrics"]["treasures_collected"], 3),
        "team_return": round(result["mean_return"], 2),
        "success_rate": round(result["success_rate"], 3),
        "mean_length": round(result["mean_length"], 2),
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", choices=sorted(ALGOS), default="ppo")
    parser.add_argument("--n-timesteps", type=int, default=150_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--params", type=json.loads, default={})
    parser.add_argument("--env-kwargs", type=json.loads, default={"observation": "egocentric"})
    parser.add_argument("--n-eval", type=int, default=100)
    parser.add_argument("--tag", default="")
    args = parser.parse_args(argv)
    rows = []
    for seed in args.seeds:
        row = run(args.algo, args.params, args.env_kwargs, args.n_timesteps, seed, args.n_eval)
        rows.append(row)
        print(json.dumps({"tag": args.tag, **row}), flush=True)
    summary = {
        "tag": args.tag,
        "algo": args.algo,
        "params": args.params,
        "env_kwargs": args.env_kwargs,
        "n_timesteps": args.n_timesteps,
        "mean_treasures": round(float(np.mean([r["treasures"] for r in rows])), 3),
        "min_treasures": min(r["treasures"] for r in rows),
        "mean_train_s": round(float(np.mean([r["train_s"] for r in rows])), 1),
        "max_train_s": max(r["train_s"] for r in rows),
    }
    print("SUMMARY " + json.dumps(summary), flush=True)


if __name__ == "__main__":
    main()
