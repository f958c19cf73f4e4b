"""Export a trained SB3 policy to ONNX (optionally int8) for torch-free inference (``sbagents.serve``).

The exported graph maps a raw observation batch to the action ``model.predict(deterministic=True)``
returns: VecNormalize observation normalization (``clip((obs - mean) / sqrt(var + eps), -clip, clip)``),
the deterministic policy, tanh squashing and rescaling to the Box bounds (or clipping, for unsquashed
Gaussian policies) are all inside the graph. Discrete actions come out as the int64 argmax index;
Discrete observations go in as an int64 index (one-hot inside the graph).

We use the legacy TorchScript exporter (``dynamo=False``): it needs no ``onnxscript`` and traces SB3's
distributions as they are; its deprecation warning is silenced locally. Argument validation of
``torch.distributions`` is switched off while tracing (it would add data-dependent checks) and restored.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import tempfile
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import onnxruntime as ort
import torch
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

OBS_INPUT = "obs"
ACTION_OUTPUT = "action"
ONNX_OPSET = 17


class OnnxPolicy(torch.nn.Module):
    """Raw observation ``(batch, obs_dim)`` (or ``(batch,)`` int64 for Discrete) -> action
    ``(batch, act_dim)`` float32 for Box, ``(batch,)`` int64 for Discrete.

    :param model: the trained SB3 algorithm.
    :param obs_rms: VecNormalize observation statistics to bake in (None: no normalization).
    :param clip_obs: VecNormalize ``clip_obs``.
    :param epsilon: VecNormalize ``epsilon``.
    """

    obs_mean: torch.Tensor
    obs_scale: torch.Tensor
    act_low: torch.Tensor
    act_high: torch.Tensor

    def __init__(
        self,
        model: BaseAlgorithm,
        obs_rms: RunningMeanStd | None = None,
        clip_obs: float = 10.0,
        epsilon: float = 1e-8,
    ) -> None:
        super().__init__()
        self.policy = model.policy
        self.action_space = model.action_space
        self.clip_obs = float(clip_obs)
        self.normalize = obs_rms is not None
        if obs_rms is not None:
            self.register_buffer("obs_mean", torch.as_tensor(obs_rms.mean, dtype=torch.float32))
            scale = np.sqrt(obs_rms.var + epsilon)
            self.register_buffer("obs_scale", torch.as_tensor(scale, dtype=torch.float32))
        self.box = isinstance(self.action_space, spaces.Box)
        if self.box:
            assert isinstance(self.action_space, spaces.Box)
            self.register_buffer("act_low", torch.as_tensor(self.action_space.low, dtype=torch.float32))
            self.register_buffer("act_high", torch.as_tensor(self.action_space.high, dtype=torch.float32))
        self.squash = bool(getattr(self.policy, "squash_output", False))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        if self.normalize:
            obs = torch.clamp((obs - self.obs_mean) / self.obs_scale, -self.clip_obs, self.clip_obs)
        action = self.policy._predict(obs, deterministic=True)
        if not self.box:
            return action.long()
        action = action.float().reshape((-1, *self.act_low.shape))
        if self.squash:
            return self.act_low + 0.5 * (action + 1.0) * (self.act_high - self.act_low)
        return torch.max(torch.min(action, self.act_high), self.act_low)


def _dummy_obs(space: spaces.Space[Any]) -> torch.Tensor:
    if isinstance(space, spaces.Discrete):
        return torch.zeros((1,), dtype=torch.int64)
    if isinstance(space, spaces.Box):
        return torch.as_tensor(space.sample()[None], dtype=torch.float32)
    raise TypeError(f"only Box and Discrete observation spaces can be exported, got {space}")


def export_onnx(
    model: BaseAlgorithm,
    out_path: str | Path,
    obs_rms: RunningMeanStd | None = None,
    clip_obs: float = 10.0,
    epsilon: float = 1e-8,
) -> Path:
    """Write ``model``'s deterministic policy (with normalization and action rescaling baked in) as ONNX.

    :param model: a DQN, PPO, A2C, SAC, TD3 or DDPG model (Box or Discrete actions).
    :param out_path: destination ``.onnx`` file (parents are created).
    :param obs_rms: ``VecNormalize.obs_rms`` when the model was trained on normalized observations.
    :param clip_obs: ``VecNormalize.clip_obs``.
    :param epsilon: ``VecNormalize.epsilon``.
    :return: the written path. Input ``obs`` ``(batch, *obs_shape)`` float32 (int64 ``(batch,)`` for
        Discrete observations), output ``action`` ``(batch, *act_shape)`` float32 or ``(batch,)`` int64.
    """
    if not isinstance(model.action_space, spaces.Box | spaces.Discrete):
        raise TypeError(f"only Box and Discrete action spaces can be exported, got {model.action_space}")
    if obs_rms is not None and not isinstance(obs_rms, RunningMeanStd):
        raise TypeError("obs_rms must be a RunningMeanStd (dict observations are not supported)")
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    device = model.policy.device
    wrapper = OnnxPolicy(model, obs_rms, clip_obs, epsilon).cpu().eval()  # moves model.policy to CPU
    model.policy.set_training_mode(False)
    dummy = _dummy_obs(model.observation_space)
    validate = torch.distributions.Distribution._validate_args
    torch.distributions.Distribution.set_default_validate_args(False)
    try:
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore", DeprecationWarning)
            warnings.simplefilter("ignore", FutureWarning)
            warnings.simplefilter("ignore", torch.jit.TracerWarning)
            torch.onnx.export(
                wrapper,
                (dummy,),
                str(out),
                dynamo=False,
                input_names=[OBS_INPUT],
                output_names=[ACTION_OUTPUT],
                dynamic_axes={OBS_INPUT: {0: "batch"}, ACTION_OUTPUT: {0: "batch"}},
                opset_version=ONNX_OPSET,
            )
    finally:
        torch.distributions.Distribution.set_default_validate_args(validate)
        model.policy.to(device)  # back where the caller had it
    return out


def quantize_int8(src: str | Path, dst: str | Path) -> Path:
    """Dynamic int8 weight quantization of an ONNX file (``onnxruntime.quantization``, QInt8 weights)."""
    from onnxruntime.quantization import QuantType, quantize_dynamic

    dst = Path(dst)
    dst.parent.mkdir(parents=True, exist_ok=True)
    # onnxruntime logs a root-logger hint about shape pre-processing; it changes nothing for these MLPs
    # (measured: identical int8 weights), so drop that one message while quantizing.
    hint = _DropMessage("Please consider to run pre-processing")
    logging.getLogger().addFilter(hint)
    try:
        quantize_dynamic(str(src), str(dst), weight_type=QuantType.QInt8)
    finally:
        logging.getLogger().removeFilter(hint)
    return dst


class _DropMessage(logging.Filter):
    def __init__(self, prefix: str) -> None:
        super().__init__()
        self.prefix = prefix

    def filter(self, record: logging.LogRecord) -> bool:  # noqa: D102
        return not str(record.msg).startswith(self.prefix)


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
    actions, _ = model.predict(obs, deterministic=True)  # type: ignore[arg-type]
    return np.asarray(actions)


def _action_pairs(
    model: BaseAlgorithm, onnx_path: str | Path, observations: np.ndarray, vec_normalize: VecNormalize | None
) -> tuple[np.ndarray, np.ndarray]:
    """``(onnx actions, SB3 actions)`` as float64 arrays of the same shape ``(N, *act_shape)``."""
    session = _session(onnx_path)
    onnx_actions = session.run(None, {OBS_INPUT: _onnx_input(session, observations)})[0]
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
        x = vec_normalize.normalize_obs(obs) if vec_normalize is not None else obs
        model.predict(x, deterministic=True)  # type: ignore[arg-type]
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


@dataclass
class ExportReport:
    """What :func:`export_run` wrote and measured.

    ``parity_*``: max abs action difference vs SB3; ``int8_deviation``: :func:`action_deviation` of the int8 file,
    ``int8_acceptable``: whether it is within :data:`INT8_TOLERANCE` for the action space (``action_kind``:
    ``box`` or ``discrete``).
    """

    onnx_path: Path
    sidecar_path: Path
    parity_fp32: float
    onnx_bytes: int
    int8_path: Path | None = None
    parity_int8: float | None = None
    int8_bytes: int | None = None
    int8_deviation: float | None = None
    int8_acceptable: bool | None = None
    action_kind: str = "box"
    n_parity_observations: int = 0
    latency: dict[str, dict[str, float]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (paths as str)."""
        return {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(self).items()}


def _space_meta(space: spaces.Space[Any]) -> dict[str, Any]:
    if isinstance(space, spaces.Discrete):
        return {"type": "discrete", "n": int(space.n), "start": int(space.start)}
    assert isinstance(space, spaces.Box), f"unsupported space {space}"
    low, high = (np.asarray(b, dtype=np.float64).ravel().tolist() for b in (space.low, space.high))
    return {"type": "box", "shape": list(space.shape), "low": low, "high": high}


def check_exportable(model: BaseAlgorithm) -> None:
    """Raise ``TypeError`` (one line: what is wrong, what works) unless ``model`` can be exported to ONNX."""
    if not any(p.requires_grad for p in model.policy.parameters()):
        raise TypeError(
            f"export writes neural-network policies to ONNX; {type(model).__name__}'s policy is a table with no "
            "network (its values are in the model .zip)"
        )
    for what, space in (("observation", model.observation_space), ("action", model.action_space)):
        if not isinstance(space, spaces.Box | spaces.Discrete):
            raise TypeError(f"export supports Box and Discrete spaces; the {what} space is {space}")


def export_run(
    model: BaseAlgorithm,
    vec_normalize: VecNormalize | None,
    out_dir: str | Path,
    int8: bool,
    env_id: str,
    obs_names: Sequence[str] | None = None,
    action_names: Sequence[str] | None = None,
    env: gym.Env[Any, Any] | VecEnv | None = None,
    n_observations: int = 1000,
    seed: int = 0,
    latency_n: int = 1000,
) -> ExportReport:
    """Export, quantize (``int8``), check parity and latency, and write the ``policy.json`` sidecar.

    Writes ``policy.onnx`` (+ ``policy.int8.onnx``) and ``policy.json`` (env id, algo, obs/action names,
    spaces with bounds, ONNX input/output names, parity and latency) into ``out_dir``. The files are made in a
    staging folder inside ``out_dir`` and moved in at the end, so a failure leaves no partial export.
    Parity observations are recorded from ``env`` (default ``gym.make(env_id)``) with the greedy policy.

    :raises TypeError: the model cannot be exported (:func:`check_exportable`).
    :raises ValueError: ``n_observations < 1``.
    """
    check_exportable(model)
    if n_observations < 1:
        raise ValueError(f"n_observations must be >= 1, got {n_observations}")
    out = Path(out_dir)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".staging-", dir=out))
    try:
        report = _export_into(model, vec_normalize, staging, out, int8, env_id, obs_names, action_names, env,
                              n_observations, seed, latency_n)
        for path in staging.iterdir():
            os.replace(path, out / path.name)
    except BaseException:
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return report


def _export_into(
    model: BaseAlgorithm, vec_normalize: VecNormalize | None, staging: Path, out: Path, int8: bool, env_id: str,
    obs_names: Sequence[str] | None, action_names: Sequence[str] | None, env: gym.Env[Any, Any] | VecEnv | None,
    n_observations: int, seed: int, latency_n: int,
) -> ExportReport:
    """The work of :func:`export_run`: files are written to ``staging``, the report names them in ``out``."""
    use_norm = vec_normalize is not None and vec_normalize.norm_obs
    obs_rms = vec_normalize.obs_rms if use_norm and vec_normalize is not None else None
    if obs_rms is not None and not isinstance(obs_rms, RunningMeanStd):
        raise TypeError("dict observations are not supported")
    clip_obs = vec_normalize.clip_obs if vec_normalize is not None else 10.0
    epsilon = vec_normalize.epsilon if vec_normalize is not None else 1e-8
    onnx_path = export_onnx(model, staging / "policy.onnx", obs_rms, clip_obs, epsilon)
    norm = vec_normalize if use_norm else None

    own_env = env is None
    rec_env = gym.make(env_id) if env is None else env
    try:
        plain_norm = None if isinstance(rec_env, VecNormalize) else norm
        observations = record_observations(rec_env, model, n_observations, seed, vec_normalize=plain_norm)
    finally:
        if own_env:
            rec_env.close()

    paths: dict[str, Path] = {"onnx": onnx_path}
    report = ExportReport(
        onnx_path=out / onnx_path.name, sidecar_path=out / "policy.json",
        parity_fp32=check_parity(model, onnx_path, observations, norm),
        onnx_bytes=onnx_path.stat().st_size, n_parity_observations=len(observations),
        action_kind="box" if isinstance(model.action_space, spaces.Box) else "discrete",
    )
    if int8:
        int8_path = quantize_int8(onnx_path, staging / "policy.int8.onnx")
        paths["onnx_int8"] = int8_path
        report.int8_path = out / int8_path.name
        report.int8_bytes = int8_path.stat().st_size
        report.parity_int8 = check_parity(model, int8_path, observations, norm)
        report.int8_deviation = action_deviation(model, int8_path, observations, norm)
        report.int8_acceptable = report.int8_deviation <= INT8_TOLERANCE[report.action_kind]
    report.latency = latency_table(model, paths, observations[0], latency_n, norm)

    n_obs = int(np.prod(model.observation_space.shape)) if model.observation_space.shape else 1
    n_act = int(np.prod(model.action_space.shape)) if model.action_space.shape else 1
    sidecar = {
        "env_id": env_id,
        "algo": type(model).__name__.lower(),
        "obs_names": list(obs_names) if obs_names else [f"obs_{i}" for i in range(n_obs)],
        "action_names": list(action_names) if action_names else [f"action_{i}" for i in range(n_act)],
        "observation_space": _space_meta(model.observation_space),
        "action_space": _space_meta(model.action_space),
        "input_name": OBS_INPUT,
        "output_name": ACTION_OUTPUT,
        "obs_normalization_baked_in": obs_rms is not None,
        "files": {name: p.name for name, p in paths.items()},
        "report": report.to_dict(),
    }
    (staging / "policy.json").write_text(json.dumps(sidecar, indent=2) + "\n")
    return report
