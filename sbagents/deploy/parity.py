"""How an exported ONNX policy compares with SB3's: action parity, a deviation measured in the action space's own
units (with the tolerance that makes an int8 file acceptable), single-observation latency, and the observations the
comparisons run on (recorded with the greedy policy).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import onnxruntime as ort
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sbagents.deploy.onnx_export import OBS_INPUT, predict_actions


def _session(onnx_path: str | Path) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    return ort.InferenceSession(str(onnx_path), options, providers=["CPUExecutionProvider"])


def _onnx_input(session: ort.InferenceSession, observations: np.ndarray) -> np.ndarray:
    dtype = np.int64 if "int64" in session.get_inputs()[0].type else np.float32
    return np.asarray(observations, dtype=dtype)


def _sb3_actions(
    model: BaseAlgorithm, observations: np.ndarray, vec_normalize: VecNormalize | None
) -> np.ndarray:
    obs = vec_normalize.normalize_obs(observations) if vec_normalize is not None else observations
    return predict_actions(model, np.asarray(obs))


def _action_pairs(
    model: BaseAlgorithm, onnx_path: str | Path, observations: np.ndarray, vec_normalize: VecNormalize | None
) -> tuple[np.ndarray, np.ndarray]:
    """``(onnx actions, SB3 actions)`` as float64 arrays of the same shape ``(N, *act_shape)``."""
    session = _session(onnx_path)
    onnx_actions = np.asarray(session.run(None, {OBS_INPUT: _onnx_input(session, observations)})[0])
    sb3_actions = _sb3_actions(model, observations, vec_normalize).astype(np.float64)
    return onnx_actions.astype(np.float64).reshape(sb3_actions.shape), sb3_actions


def check_parity(
    model: BaseAlgorithm,
    onnx_path: str | Path,
    observations: np.ndarray,
    vec_normalize: VecNormalize | None = None,
) -> float:
    """Max abs action difference between the ONNX graph and ``model.predict(..., deterministic=True)``.

    :param observations: raw (unnormalized) observations ``(N, *obs_shape)`` (``(N,)`` for Discrete).
    :param vec_normalize: the VecNormalize the model was trained with (its statistics normalize the
        SB3 side; the ONNX side has them baked in).
    """
    onnx_actions, sb3_actions = _action_pairs(model, onnx_path, observations, vec_normalize)
    diff = np.abs(onnx_actions - sb3_actions)
    return float(diff.max()) if diff.size else 0.0


#: The largest deviation of an int8 policy called acceptable: 5% of a Box action's range (per dimension), or
#: 1% of observations with a different Discrete action.
INT8_TOLERANCE = {"box": 0.05, "discrete": 0.01}


def action_deviation(
    model: BaseAlgorithm,
    onnx_path: str | Path,
    observations: np.ndarray,
    vec_normalize: VecNormalize | None = None,
) -> float:
    """How far the ONNX policy strays from SB3's, in units that mean something for the action space.

    Box actions: the max over observations and dimensions of ``|a_onnx - a_sb3| / (high - low)`` (a share of
    the action range); Discrete actions: the share of observations whose action differs.
    """
    onnx_actions, sb3_actions = _action_pairs(model, onnx_path, observations, vec_normalize)
    space = model.action_space
    if isinstance(space, spaces.Box):
        width = np.asarray(space.high, dtype=np.float64) - np.asarray(space.low, dtype=np.float64)
        rel = np.abs(onnx_actions - sb3_actions) / np.where(np.isfinite(width) & (width > 0), width, 1.0)
        return float(rel.max()) if rel.size else 0.0
    return float(np.mean(onnx_actions != sb3_actions)) if sb3_actions.size else 0.0


def _percentiles(samples: list[float]) -> dict[str, float]:
    arr = np.asarray(samples) * 1e6
    return {"p50_us": float(np.percentile(arr, 50)), "p99_us": float(np.percentile(arr, 99))}


def latency_table(
    model: BaseAlgorithm,
    onnx_paths: Mapping[str, str | Path],
    observation: np.ndarray,
    n: int = 1000,
    vec_normalize: VecNormalize | None = None,
) -> dict[str, dict[str, float]]:
    """Single-observation latency (p50/p99 in microseconds) of SB3 predict and each ONNX file.

    :param onnx_paths: name -> ONNX file (e.g. ``{"onnx": ..., "onnx_int8": ...}``).
    :param observation: one raw observation ``(*obs_shape)``.
    :return: ``{"sb3_predict": {...}, name: {...}}``; the SB3 row includes ``normalize_obs``.
    """
    obs = np.asarray(observation)
    table: dict[str, dict[str, float]] = {}
    samples: list[float] = []
    for i in range(n + 10):
        t0 = time.perf_counter()
        x = np.asarray(vec_normalize.normalize_obs(obs) if vec_normalize is not None else obs)
        predict_actions(model, x[None])
        if i >= 10:
            samples.append(time.perf_counter() - t0)
    table["sb3_predict"] = _percentiles(samples)
    for name, path in onnx_paths.items():
        session = _session(path)
        feed = {OBS_INPUT: _onnx_input(session, obs[None])}
        samples = []
        for i in range(n + 10):
            t0 = time.perf_counter()
            session.run(None, feed)
            if i >= 10:
                samples.append(time.perf_counter() - t0)
        table[name] = _percentiles(samples)
    return table


def record_observations(
    env: gym.Env[Any, Any] | VecEnv,
    model: BaseAlgorithm,
    n: int = 1000,
    seed: int = 0,
    deterministic: bool = True,
    vec_normalize: VecNormalize | None = None,
) -> np.ndarray:
    """Raw (unnormalized) observations ``(n, *obs_shape)`` met while ``model`` acts in ``env``.

    :param env: a Gymnasium env or a VecEnv. A VecNormalize env is used for its statistics only: they
        are frozen while recording (``training`` is restored afterwards) and the original observations
        are returned.
    :param vec_normalize: statistics to normalize observations with before ``predict`` when ``env``
        itself does not normalize (e.g. a plain env and a model trained under VecNormalize).
    """
    out: list[np.ndarray] = []

    def act(obs: Any) -> Any:
        x = vec_normalize.normalize_obs(obs) if vec_normalize is not None else obs
        return model.predict(x, deterministic=deterministic)[0]

    if isinstance(env, VecEnv):
        norm = env if isinstance(env, VecNormalize) else None
        was_training = norm.training if norm is not None else False
        if norm is not None:
            norm.training = False
        try:
            env.seed(seed)
            obs = env.reset()
            while len(out) < n:
                out.extend(np.asarray(norm.get_original_obs() if norm is not None else obs))
                obs = env.step(act(obs))[0]
        finally:
            if norm is not None:
                norm.training = was_training
    else:
        obs_, _ = env.reset(seed=seed)
        while len(out) < n:
            out.append(np.asarray(obs_))
            action = act(np.asarray(obs_)[None])[0]
            obs_, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                obs_, _ = env.reset()
    return np.stack(out[:n])
