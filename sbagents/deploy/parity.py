"""How an exported ONNX policy compares with SB3's: action parity, a deviation measured in the action space's own
units (with the tolerance that makes an int8 file acceptable), single-observation latency, and the observations the
comparisons run on (recorded with the greedy policy).

A recurrent policy is compared over whole recorded episodes (a :class:`Recording`: observations and episode starts
in time order): both sides start from a zero state and carry their own state from step to step, so a difference
that builds up in the memory shows in the actions and in :func:`state_parity`.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import onnxruntime as ort
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sbagents.callbacks.episodes import model_actor
from sbagents.deploy.onnx_export import (
    OBS_INPUT,
    START_INPUT,
    STATE_INPUTS,
    predict_actions,
    state_shape,
)


@dataclass(frozen=True)
class Recording:
    """Raw observations met while a policy acted, in time order: ``observations`` ``(T, B, *obs_shape)`` (``B``
    env slots stepped together) and ``starts`` ``(T, B)`` bools, True where a slot's episode starts."""

    observations: np.ndarray
    starts: np.ndarray

    def flat(self) -> np.ndarray:
        """The observations as one batch ``(T * B, *obs_shape)``."""
        return self.observations.reshape((-1, *self.observations.shape[2:]))

    def __len__(self) -> int:
        return int(self.observations.shape[0] * self.observations.shape[1])


Observations = np.ndarray | Recording


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
    model: BaseAlgorithm, onnx_path: str | Path, observations: Observations, vec_normalize: VecNormalize | None
) -> tuple[np.ndarray, np.ndarray]:
    """``(onnx actions, SB3 actions)`` as float64 arrays of the same shape ``(N, *act_shape)``."""
    if state_shape(model) is not None:
        onnx_actions, sb3_actions, _ = _sequence_pairs(model, onnx_path, _recording(observations), vec_normalize)
        return onnx_actions, sb3_actions
    flat = observations.flat() if isinstance(observations, Recording) else observations
    session = _session(onnx_path)
    onnx_actions = np.asarray(session.run(None, {OBS_INPUT: _onnx_input(session, flat)})[0])
    sb3_actions = _sb3_actions(model, flat, vec_normalize).astype(np.float64)
    return onnx_actions.astype(np.float64).reshape(sb3_actions.shape), sb3_actions


def _recording(observations: Observations) -> Recording:
    if not isinstance(observations, Recording):
        raise ValueError("a recurrent policy is compared over whole episodes: pass a Recording (observations and "
                         "episode starts in time order), not a batch of observations")
    return observations


def zero_state_feed(session: ort.InferenceSession, batch: int) -> dict[str, np.ndarray]:
    """The state inputs of a recurrent graph at the first step of ``batch`` episodes (zeros, episode starts 1);
    ``{}`` for a stateless graph."""
    shapes = {i.name: i.shape for i in session.get_inputs()}
    if STATE_INPUTS[0] not in shapes:
        return {}
    layers, hidden = int(shapes[STATE_INPUTS[0]][0]), int(shapes[STATE_INPUTS[0]][2])
    zeros = np.zeros((layers, batch, hidden), dtype=np.float32)
    return {STATE_INPUTS[0]: zeros, STATE_INPUTS[1]: zeros.copy(), START_INPUT: np.ones(batch, dtype=np.float32)}


def _sequence_pairs(
    model: BaseAlgorithm, onnx_path: str | Path, recording: Recording, vec_normalize: VecNormalize | None
) -> tuple[np.ndarray, np.ndarray, float]:
    """Step the ONNX graph and SB3's ``predict`` through ``recording``, each carrying its own state: ``(onnx
    actions, SB3 actions, max abs state difference)``, actions ``(T * B, *act_shape)`` float64."""
    session = _session(onnx_path)
    policy = model_actor(model, deterministic=True)
    state: Any = None
    onnx_state: tuple[np.ndarray, ...] | None = None
    onnx_out, sb3_out, state_diff = [], [], 0.0
    for obs, starts in zip(recording.observations, recording.starts, strict=True):
        x = vec_normalize.normalize_obs(obs) if vec_normalize is not None else obs
        action, state = policy(np.asarray(x), state, np.asarray(starts, dtype=bool))
        feed = {OBS_INPUT: _onnx_input(session, obs)}
        if onnx_state is None:
            feed.update(zero_state_feed(session, len(obs)))
        else:
            feed.update({STATE_INPUTS[0]: onnx_state[0], STATE_INPUTS[1]: onnx_state[1]})
        feed[START_INPUT] = np.asarray(starts, dtype=np.float32)
        onnx_action, *onnx_next = session.run(None, feed)
        onnx_state = tuple(np.asarray(v, dtype=np.float32) for v in onnx_next)
        sb3 = np.asarray(action, dtype=np.float64)
        sb3_out.append(sb3)
        onnx_out.append(np.asarray(onnx_action, dtype=np.float64).reshape(sb3.shape))
        state_diff = max(state_diff, *(float(np.abs(np.asarray(a) - b).max()) for a, b in zip(state, onnx_state,
                                                                                                  strict=True)))
    return np.concatenate(onnx_out), np.concatenate(sb3_out), state_diff


def state_parity(
    model: BaseAlgorithm, onnx_path: str | Path, recording: Recording, vec_normalize: VecNormalize | None = None
) -> float:
    """Max abs difference of the hidden and cell states of a recurrent ONNX graph and SB3's ``predict``, each
    carrying its own state through ``recording`` (0.0 for a stateless policy)."""
    if state_shape(model) is None:
        return 0.0
    return _sequence_pairs(model, onnx_path, recording, vec_normalize)[2]


def check_parity(
    model: BaseAlgorithm,
    onnx_path: str | Path,
    observations: Observations,
    vec_normalize: VecNormalize | None = None,
) -> float:
    """Max abs action difference between the ONNX graph and ``model.predict(..., deterministic=True)``.

    :param observations: raw (unnormalized) observations ``(N, *obs_shape)`` (``(N,)`` for Discrete), or a
        :class:`Recording` (required for a recurrent policy: compared over its episodes, state carried).
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
    observations: Observations,
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
        feed = {OBS_INPUT: _onnx_input(session, obs[None]), **zero_state_feed(session, 1)}
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
    """Raw (unnormalized) observations ``(n, *obs_shape)`` met while ``model`` acts in ``env`` (its state carried:
    :func:`record_episodes`).

    :param env: a Gymnasium env or a VecEnv. A VecNormalize env is used for its statistics only: they
        are frozen while recording (``training`` is restored afterwards) and the original observations
        are returned.
    :param vec_normalize: statistics to normalize observations with before ``predict`` when ``env``
        itself does not normalize (e.g. a plain env and a model trained under VecNormalize).
    """
    return record_episodes(env, model, n, seed, deterministic, vec_normalize).flat()[:n]


#: Most steps a recording of whole episodes goes on past its ``n`` observations (a policy that never ends its
#: episode cannot hold an export forever).
MAX_EXTRA_STEPS = 10_000


def recording_goes_on(count: int, n: int, whole: bool, ended: np.ndarray, steps: int) -> bool:
    """Whether a recording of ``count`` observations (``steps`` steps) goes on: below ``n``, or (``whole``) until
    every slot's episode has ended since (``ended``), within :data:`MAX_EXTRA_STEPS` more steps."""
    if count < n:
        return True
    return whole and not bool(np.all(ended)) and steps < n + MAX_EXTRA_STEPS


def record_episodes(
    env: gym.Env[Any, Any] | VecEnv,
    model: BaseAlgorithm,
    n: int = 1000,
    seed: int = 0,
    deterministic: bool = True,
    vec_normalize: VecNormalize | None = None,
) -> Recording:
    """At least ``n`` raw observations met while ``model`` acts in ``env`` through the one policy protocol (a
    recurrent policy keeps its state, reset at episode starts), in time order: ``(T, B, *obs_shape)`` for a VecEnv
    of ``B`` envs (``B = 1`` for a Gymnasium env), with their episode starts. For a recurrent policy the recording
    goes on until every env's episode in progress at the ``n``-th observation has ended (whole episodes; at most
    ``MAX_EXTRA_STEPS`` more steps). The options are :func:`record_observations`'."""
    policy = model_actor(model, deterministic)
    whole = state_shape(model) is not None
    out: list[np.ndarray] = []
    starts_out: list[np.ndarray] = []
    state: Any = None

    def act(obs: Any, starts: np.ndarray) -> Any:
        nonlocal state
        x = vec_normalize.normalize_obs(obs) if vec_normalize is not None else obs
        actions, state = policy(x, state, starts)
        return actions

    if isinstance(env, VecEnv):
        norm = env if isinstance(env, VecNormalize) else None
        was_training = norm.training if norm is not None else False
        if norm is not None:
            norm.training = False
        try:
            env.seed(seed)
            obs = env.reset()
            starts = np.ones(env.num_envs, dtype=bool)
            ended = np.zeros(env.num_envs, dtype=bool)
            while recording_goes_on(len(out) * env.num_envs, n, whole, ended, len(out)):
                out.append(np.asarray(norm.get_original_obs() if norm is not None else obs))
                starts_out.append(starts)
                obs, _, dones, _ = env.step(act(obs, starts))
                starts = np.asarray(dones, dtype=bool)
                if len(out) * env.num_envs >= n:
                    ended |= starts
        finally:
            if norm is not None:
                norm.training = was_training
    else:
        obs_, _ = env.reset(seed=seed)
        start = True
        while recording_goes_on(len(out), n, whole, np.array([start and len(out) >= n]), len(out)):
            out.append(np.asarray(obs_)[None])
            starts_out.append(np.array([start]))
            action = act(np.asarray(obs_)[None], starts_out[-1])[0]
            obs_, _, terminated, truncated, _ = env.step(action)
            start = bool(terminated or truncated)
            if start:
                obs_, _ = env.reset()
    return Recording(np.stack(out), np.stack(starts_out))
