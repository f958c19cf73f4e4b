"""Hyperparameter / observation search for parameter-shared SB3 agents on ``treasure_hunt_v0``.

One run = train ``algo`` with the given hyperparameters for ``n_timesteps`` env (agent) steps, measure the
wall time of ``model.learn`` only, then evaluate the deterministic team on 100 seeded episodes
(:func:`sbagents.multiagent.team_eval.evaluate_team`). A search helper with no results file or section of its own
(the chosen config is the shipped ``zoo_configs/ppo.yml`` entry, measured by benchmark ``treasure-hunt-learning``).

Example (the final PPO config), one seed::

    run("ppo", {"n_envs": 8, "n_steps": 64, "batch_size": 256, "n_epochs": 4, "learning_rate": 0.001},
        {"observation": "egocentric"}, 150_000, seed=0)

``params`` is a mapping with ``n_envs``, ``net_arch``, ``activation_fn`` (``tanh``/``relu``) and the algorithm's
constructor kwargs; ``env_kwargs`` a mapping for ``parallel_env``.
"""

from __future__ import annotations

import time
from typing import Any

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
