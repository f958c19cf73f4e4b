"""``export`` of an RLlib run on a Gymnasium env: its module (rebuilt from the checkpoint's plain data) written as
``policy.onnx`` with the same sidecar, parity and latency report as an SB3 run's (:mod:`sbagents.deploy.exporting`).

:class:`RllibModel` gives the module the two faces the export machinery reads: a torch ``policy`` whose
``_predict`` is the module's greedy action (:func:`~sbagents.rllib.single_agent.greedy_actions`, traced into the
graph, with RLlib's action unsquashing after it), and SB3's ``predict`` (what ``evaluate`` does with the module), which
the parity check compares the graph with. The graph takes the observations RLlib's env runners give the module
(Atari: RLlib's 64x64x4 float frames; the sidecar names that preprocessing).
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from ray.rllib.core.rl_module.rl_module import RLModule
from stable_baselines3.common.vec_env import DummyVecEnv

from sbagents.atomic import run_subfolder
from sbagents.core.env_kinds import EnvKind, SingleAgentKind
from sbagents.core.env_names import EnvRef
from sbagents.core.run_dir import load_run_config
from sbagents.deploy.exporting import ExportChecks, ExportReport, export_run
from sbagents.errors import UsageError
from sbagents.rllib import CHECKPOINT_DIR
from sbagents.rllib.checkpoints import action_settings, load_modules
from sbagents.rllib.single_agent import (
    ATARI_DIM,
    ATARI_STACK,
    SINGLE_MODULE,
    greedy_actions,
    module_policy,
    single_vec_env,
)


class RllibActor(torch.nn.Module):
    """An RLlib module's greedy actor in SB3's policy protocol (``_predict``, ``set_training_mode``, ``device``,
    ``squash_output``): observations ``(batch, *obs_shape)`` -> actions ``(batch,)`` indices or ``(batch, act_dim)``
    in [-1, 1] (``squash_output``: RLlib's ``normalize_actions``; the export rescales them to the bounds)."""

    def __init__(self, module: RLModule, observation_space: spaces.Space[Any], action_space: spaces.Space[Any],
                 normalize_actions: bool = True) -> None:
        super().__init__()
        assert isinstance(module, torch.nn.Module)
        self.module = module
        self.observation_space, self.action_space = observation_space, action_space
        self.squash_output = isinstance(action_space, spaces.Box) and normalize_actions

    @property
    def device(self) -> torch.device:
        return torch.device("cpu")

    def set_training_mode(self, mode: bool) -> None:
        self.train(mode)

    def _predict(self, observation: torch.Tensor, deterministic: bool = True) -> torch.Tensor:
        with _traceable_nanmean() if torch.jit.is_tracing() else contextlib.nullcontext():
            actions = greedy_actions(self.module, observation.float())
        return torch.clamp(actions, -1.0, 1.0) if self.squash_output else actions  # unsquash_action clips first


@contextlib.contextmanager
def _traceable_nanmean() -> Iterator[None]:
    """While the ONNX export traces the module: ``Tensor.nanmean`` as ``Tensor.mean``, which ONNX has (opset 17 has
    no ``nanmean``). RLlib's dueling DQN head centres its advantages with ``nanmean`` so that masked actions (-inf,
    made NaN) are left out; the export's observations carry no mask, so both give the same values."""
    original = torch.Tensor.nanmean

    def mean(self: torch.Tensor, dim: Any = None, keepdim: bool = False, **kwargs: Any) -> torch.Tensor:
        return self.mean(dim=dim, keepdim=keepdim, **kwargs)

    torch.Tensor.nanmean = mean  # type: ignore[assignment,method-assign]
    try:
        yield
    finally:
        torch.Tensor.nanmean = original  # type: ignore[method-assign]


class RllibModel:
    """What :func:`~sbagents.deploy.exporting.export_run` reads of a model, for an RLlib module: ``policy``
    (:class:`RllibActor`), the spaces, and ``predict`` (the module acting as ``evaluate`` plays it)."""

    def __init__(self, module: RLModule, observation_space: spaces.Space[Any], action_space: spaces.Space[Any],
                 actions: dict[str, bool]) -> None:
        self.policy = RllibActor(module, observation_space, action_space, actions["normalize"])
        self.observation_space, self.action_space = observation_space, action_space
        self._act = {greedy: module_policy(module, action_space, greedy, actions)
                     for greedy in (True, False)}

    def predict(self, observation: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:
        obs = np.asarray(observation, dtype=np.float32)
        single = obs.shape == self.observation_space.shape
        actions = self._act[deterministic](obs[None] if single else obs)
        return (actions[0] if single else actions), None


def export_rllib_run(run_dir: str | Path, algo: str, ref: EnvRef, int8: bool = False, out: str | Path | None = None,
                     n_observations: int = 1000, trust: bool = False) -> dict[str, ExportReport]:
    """Export an RLlib run's module to ONNX in ``out`` (default ``<run dir>/export``): ``{"shared": report}``.

    :raises UsageError: a team run (not exported yet), or a run that cannot be loaded.
    """
    if n_observations < 1:
        raise UsageError(f"--n-observations must be >= 1, got {n_observations}")
    run_dir = Path(run_dir)
    kwargs = dict(load_run_config(run_dir, ref.env_id).get("env_kwargs") or {})
    modules = load_modules(run_dir / CHECKPOINT_DIR, ref, kwargs, trust)
    target = Path(out) if out is not None else run_subfolder(run_dir, "export", create=False)
    return _export_kind(ref.kind, modules, run_dir, ref, kwargs, algo, target, int8,
                        ExportChecks(n_observations=n_observations))


@functools.singledispatch
def _export_kind(kind: EnvKind, modules: dict[str, RLModule], run_dir: Path, ref: EnvRef, kwargs: dict[str, Any],
                 algo: str, target: Path, int8: bool, checks: ExportChecks) -> dict[str, ExportReport]:
    raise UsageError(f"export takes RLlib runs on Gymnasium envs; {ref.env_id} is a {kind.name} env (evaluate and "
                     "record_video play its run)")


@_export_kind.register
def _export_single_agent(kind: SingleAgentKind, modules: dict[str, RLModule], run_dir: Path, ref: EnvRef,
                         kwargs: dict[str, Any], algo: str, target: Path, int8: bool,
                         checks: ExportChecks) -> dict[str, ExportReport]:
    venv = single_vec_env(ref, kwargs)
    try:
        model = RllibModel(modules[SINGLE_MODULE], venv.observation_space, venv.action_space,
                           action_settings(run_dir / CHECKPOINT_DIR))
        report = export_run(model, target, ref.env_id, env=venv, int8=int8, checks=checks,  # type: ignore[arg-type]
                            preprocessing=_preprocessing(ref, venv), algo=algo)
    finally:
        venv.close()
    return {"shared": report}


def _preprocessing(ref: EnvRef, venv: DummyVecEnv) -> dict[str, Any] | None:
    """What the env runners' env does before the module (:func:`~sbagents.rllib.single_agent.build_env`), for the
    sidecar: RLlib's Atari preprocessing, or the flattening of an observation space."""
    if ref.is_atari:
        return {"env_wrapper": [{"class": "ray.rllib.env.wrappers.atari_wrappers.wrap_atari_for_new_api_stack",
                                 "kwargs": {"dim": ATARI_DIM, "framestack": ATARI_STACK}}], "frame_stack": 0}
    raw = venv.envs[0].unwrapped.observation_space
    if raw != venv.observation_space:
        return {"env_wrapper": [{"class": "gymnasium.wrappers.FlattenObservation", "kwargs": {}}], "frame_stack": 0}
    return None
