"""SmartHome learning experiment: train zoo-style configs on several seeds, report comfort and wall time.

For each candidate (an RL Zoo style hyperparameter mapping, see ``CANDIDATES``) and seed, trains an SB3
agent on ``sbagents/SmartHome-v0`` with one torch thread, then runs the greedy policy for
``eval_episodes`` episodes and reports the comfort ``criterion_share`` (share of steps after step 10
with temperature within 1 C and light within 5 lux of the preferences), averaged over episodes.

A search helper with no results file or section of its own (the chosen candidates are the shipped zoo entries,
measured by benchmark ``learning-smarthome``). Usage::

    torch.set_num_threads(1)
    run("ddpg_fast", seed=0, eval_episodes=100)          # algo, candidate, seed, seconds, comfort
    run("ddpg_fast", 0, 100, export_dir=Path("export"))  # also export to ONNX and check parity
    print(zoo_yaml("ddpg"))                               # the recommended zoo entry

This module interprets the zoo keys itself (n_timesteps, n_envs, policy, normalize, policy_kwargs,
noise_type/noise_std, algorithm kwargs) so it runs before/without the project's config loader.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
import yaml
from stable_baselines3 import DDPG, PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise
from stable_baselines3.common.vec_env import VecNormalize

ENV_ID = "sbagents/SmartHome-v0"
ALGOS: dict[str, type[BaseAlgorithm]] = {"ddpg": DDPG, "td3": TD3, "sac": SAC, "ppo": PPO}
ACTIVATIONS = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}

#: Candidate configs, RL Zoo format (the value of the ``sbagents/SmartHome-v0`` key in ``<algo>.yml``).
CANDIDATES: dict[str, dict[str, Any]] = {
    "ddpg_base": {
        "algo": "ddpg", "n_timesteps": 10000, "policy": "MlpPolicy",
        "normalize": {"norm_obs": True, "norm_reward": False},
        "noise_type": "normal", "noise_std": 0.1, "policy_kwargs": {"net_arch": [64, 64]},
    },
    "ddpg_fast": {
        "algo": "ddpg", "n_timesteps": 8000, "policy": "MlpPolicy",
        "normalize": {"norm_obs": True, "norm_reward": False}, "gamma": 0.9, "learning_starts": 500,
        "learning_rate": 0.001, "batch_size": 128,
        "noise_type": "normal", "noise_std": 0.1, "policy_kwargs": {"net_arch": [64, 64]},
    },
    "ddpg_ci": {
        "algo": "ddpg", "n_timesteps": 4000, "policy": "MlpPolicy",
        "normalize": {"norm_obs": True, "norm_reward": False}, "gamma": 0.9, "learning_starts": 500,
        "learning_rate": 0.001, "batch_size": 128,
        "noise_type": "normal", "noise_std": 0.1, "policy_kwargs": {"net_arch": [64, 64]},
    },
    "td3_base": {
        "algo": "td3", "n_timesteps": 10000, "policy": "MlpPolicy",
        "normalize": {"norm_obs": True, "norm_reward": False},
        "noise_type": "normal", "noise_std": 0.1, "policy_kwargs": {"net_arch": [64, 64]},
    },
    "td3_fast": {
        "algo": "td3", "n_timesteps": 8000, "policy": "MlpPolicy",
        "normalize": {"norm_obs": True, "norm_reward": False}, "gamma": 0.9, "learning_starts": 500,
        "learning_rate": 0.001, "batch_size": 128,
        "noise_type": "normal", "noise_std": 0.1, "policy_kwargs": {"net_arch": [64, 64]},
    },
    "sac_base": {
        "algo": "sac", "n_timesteps": 10000, "policy": "MlpPolicy",
        "normalize": {"norm_obs": True, "norm_reward": False}, "policy_kwargs": {"net_arch": [64, 64]},
    },
    "sac_fast": {
        "algo": "sac", "n_timesteps": 8000, "policy": "MlpPolicy",
        "normalize": {"norm_obs": True, "norm_reward": False}, "gamma": 0.9, "learning_starts": 500,
        "learning_rate": 0.001, "batch_size": 128, "policy_kwargs": {"net_arch": [64, 64]},
    },
    "sac_lite": {
        "algo": "sac", "n_timesteps": 6000, "policy": "MlpPolicy",
        "normalize": {"norm_obs": True, "norm_reward": False}, "gamma": 0.9, "learning_starts": 500,
        "learning_rate": 0.001, "batch_size": 128, "policy_kwargs": {"net_arch": [64, 64]},
    },
    "sac_tf2": {
        "algo": "sac", "n_timesteps": 8000, "policy": "MlpPolicy",
        "normalize": {"norm_obs": True, "norm_reward": False}, "gamma": 0.9, "learning_starts": 500,
        "learning_rate": 0.001, "batch_size": 128, "train_freq": 2, "gradient_steps": 1,
        "policy_kwargs": {"net_arch": [64, 64]},
    },
    "ppo_base": {
        "algo": "ppo", "n_timesteps": 100000, "n_envs": 8, "policy": "MlpPolicy",
        "normalize": {"norm_obs": True, "norm_reward": True}, "n_steps": 256, "batch_size": 256,
        "gamma": 0.9, "gae_lambda": 0.95, "n_epochs": 10, "learning_rate": 0.001, "ent_coef": 0.0,
        "policy_kwargs": {"net_arch": [64, 64], "log_std_init": -1.0},
    },
}

#: The candidate each algorithm's ``zoo_configs/<algo>.yml`` entry should hold (measured in the report).
RECOMMENDED: dict[str, str] = {"ddpg": "ddpg_fast", "td3": "td3_fast", "sac": "sac_tf2", "ppo": "ppo_base"}


def zoo_yaml(algo: str) -> str:
    """The recommended candidate of ``algo`` as a YAML entry keyed ``sbagents/SmartHome-v0``."""
    entry = {k: v for k, v in CANDIDATES[RECOMMENDED[algo]].items() if k != "algo"}
    return yaml.safe_dump({ENV_ID: entry}, sort_keys=False, default_flow_style=None)


def _register() -> None:
    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point="sbagents.envs.smart_home:SmartHomeEnv")


def build(config: dict[str, Any], seed: int) -> tuple[BaseAlgorithm, VecNormalize | None]:
    """Build the model and its (optionally normalized) training vec env from a zoo-style config."""
    cfg = dict(config)
    algo = cfg.pop("algo")
    cfg.pop("n_timesteps")
    env = make_vec_env(ENV_ID, n_envs=int(cfg.pop("n_envs", 1)), seed=seed)
    normalize = cfg.pop("normalize", False)
    vec_norm = None
    if normalize:
        kwargs = normalize if isinstance(normalize, dict) else {}
        env = vec_norm = VecNormalize(env, **kwargs)
    noise_type, noise_std = cfg.pop("noise_type", None), float(cfg.pop("noise_std", 0.0))
    n_act = env.action_space.shape[0] if env.action_space.shape else 1
    if noise_type == "normal":
        cfg["action_noise"] = NormalActionNoise(np.zeros(n_act), noise_std * np.ones(n_act))
    elif noise_type == "ornstein-uhlenbeck":
        cfg["action_noise"] = OrnsteinUhlenbeckActionNoise(np.zeros(n_act), noise_std * np.ones(n_act))
    policy_kwargs = dict(cfg.pop("policy_kwargs", {}))
    if isinstance(policy_kwargs.get("activation_fn"), str):
        policy_kwargs["activation_fn"] = ACTIVATIONS[policy_kwargs["activation_fn"]]
    model = ALGOS[algo](cfg.pop("policy"), env, seed=seed, policy_kwargs=policy_kwargs, verbose=0, **cfg)
    return model, vec_norm


def evaluate(
    model: Any, vec_norm: VecNormalize | None, n_episodes: int = 100, seed: int = 10_000
) -> dict[str, float]:
    """Greedy rollouts on ``n_episodes`` fresh episodes; mean of the per-episode comfort metrics."""
    n_envs = 10
    env = make_vec_env(ENV_ID, n_envs=n_envs, seed=seed)
    per_env: list[list[dict[str, Any]]] = [[] for _ in range(n_envs)]
    metrics: list[dict[str, float]] = []
    episode_metrics = env.get_attr("episode_metrics", indices=[0])[0]
    obs = np.asarray(env.reset())
    while len(metrics) < n_episodes:
        x = vec_norm.normalize_obs(obs) if vec_norm is not None else obs
        action, _ = model.predict(x, deterministic=True)
        next_obs, _, dones, infos = env.step(action)
        obs = np.asarray(next_obs)
        for i, (done, info) in enumerate(zip(dones, infos, strict=True)):
            per_env[i].append(info)
            if done:
                metrics.append(episode_metrics(per_env[i]))
                per_env[i] = []
    keys = metrics[0].keys()
    return {k: float(np.mean([m[k] for m in metrics[:n_episodes]])) for k in keys}


class OnnxPredictor:
    """``predict``-compatible wrapper of an exported ONNX policy (raw observations in)."""

    def __init__(self, path: Path | None) -> None:
        import onnxruntime as ort

        self.session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])

    def predict(self, obs: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
        return np.asarray(self.session.run(None, {"obs": np.asarray(obs, dtype=np.float32)})[0]), None


def run(name: str, seed: int, eval_episodes: int, export_dir: Path | None = None) -> dict[str, Any]:
    """Train candidate ``name`` with ``seed``; return timings and greedy comfort metrics.

    With ``export_dir``, also export the trained policy there (``sbagents.deploy.onnx_export.export_run``, with int8)
    and add its parity / size / latency numbers to the result.
    """
    _register()
    config = CANDIDATES[name]
    t0 = time.perf_counter()
    model, vec_norm = build(config, seed)
    t1 = time.perf_counter()
    model.learn(total_timesteps=int(config["n_timesteps"]))
    t2 = time.perf_counter()
    if vec_norm is not None:
        vec_norm.training = False
    result = evaluate(model, vec_norm, eval_episodes)
    exported: dict[str, Any] = {}
    if export_dir is not None:
        from sbagents.deploy.exporting import export_run

        out_dir = export_dir / f"{name}_{seed}"
        report = export_run(model, out_dir, ENV_ID, vec_normalize=vec_norm, int8=True)
        exported = {
            k: report.to_dict()[k]
            for k in ("parity_fp32", "parity_int8", "onnx_bytes", "int8_bytes", "latency", "onnx_path")
        }
        for key, path in (("onnx", report.onnx_path), ("onnx_int8", report.int8_path)):
            onnx_metrics = evaluate(OnnxPredictor(path), None, eval_episodes)  # normalization is baked in
            exported[f"{key}_criterion_share"] = round(onnx_metrics["criterion_share"], 4)
    return {
        "algo": config["algo"], "candidate": name, "seed": seed, "n_timesteps": config["n_timesteps"],
        "train_seconds": round(t2 - t0, 2), "learn_seconds": round(t2 - t1, 2),
        **{k: round(v, 4) for k, v in result.items()},
        **exported,
    }
