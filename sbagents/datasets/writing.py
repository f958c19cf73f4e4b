"""Recorded episodes -> a Minari dataset, written atomically: the dataset is built in a hidden staging folder of the
datasets root and renamed into place, so a reader never finds a half-written dataset and an interrupted collection
leaves none.

An episode of ``T`` steps holds ``T + 1`` observations (the reset's and each step's, the terminal one included), ``T``
actions, rewards, terminations and truncations, and the infos that matter (:data:`INFO_KEYS`), ``T + 1`` values each
(Minari's layout: the reset's first).
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from sbagents.errors import UsageError

#: The info keys a dataset keeps (each step's value; a key the env never reports is left out): success, the
#: safety cost and violation (its kind as ASCII bytes, ``b""`` where none: HDF5 stores no unicode arrays), and a
#: turn-based game's legal moves of each observation (``action_mask``, bool).
INFO_KEYS = ("is_success", "cost", "violation", "action_mask")
#: A dataset id: ``namespace/name-vN`` (Minari's ``(namespace/)(env_name/)name-vN``; a namespace is required here so
#: that our datasets do not mix with others at the root).
DATASET_ID = re.compile(r"^[A-Za-z0-9_.-]+(/[A-Za-z0-9_.-]+)*/[A-Za-z0-9_.]+(-[A-Za-z0-9_.]+)*-v\d+$")
_STAGING = ".sbagents-staging."


def require_minari() -> Any:
    """The ``minari`` module, or one line naming the extra that installs it."""
    try:
        import minari
    except ImportError as exc:
        raise UsageError(f"datasets need Minari: pip install 'sbagents[data]' ({exc})") from None
    return minari


def check_dataset_id(dataset_id: str) -> str:
    """``dataset_id`` if it is ``namespace/name-vN``, else one line saying what is accepted."""
    if not DATASET_ID.match(dataset_id) or not _minari_accepts(dataset_id):
        raise UsageError(f"--dataset {dataset_id!r}: a dataset id is namespace/name-vN (a namespace of 2 characters "
                         "or more), e.g. sbagents/gridworld-expert-v0")
    return dataset_id


def _minari_accepts(dataset_id: str) -> bool:
    """Whether Minari's own parser takes ``dataset_id`` (True when Minari is not installed: it refuses later)."""
    try:
        from minari.dataset.minari_dataset import parse_dataset_id
    except ImportError:
        return True
    try:
        parse_dataset_id(dataset_id)
    except ValueError:
        return False
    return True


def datasets_root() -> Path:
    """Where datasets live: ``MINARI_DATASETS_PATH``, else Minari's default (``~/.minari/datasets``)."""
    root = os.environ.get("MINARI_DATASETS_PATH")
    return Path(root) if root else Path.home() / ".minari" / "datasets"


@dataclass
class EpisodeRecorder:
    """One episode as it is played: :meth:`start` with the reset's observation, then :meth:`step` per step."""

    observations: list[Any] = field(default_factory=list)
    actions: list[Any] = field(default_factory=list)
    rewards: list[float] = field(default_factory=list)
    terminations: list[bool] = field(default_factory=list)
    truncations: list[bool] = field(default_factory=list)
    infos: list[Mapping[str, Any]] = field(default_factory=list)

    def start(self, observation: Any, info: Mapping[str, Any] | None = None) -> None:
        """The reset's observation (and info)."""
        self.observations.append(observation)
        self.infos.append(info or {})

    def step(self, action: Any, observation: Any, reward: float, terminated: bool, truncated: bool,
             info: Mapping[str, Any]) -> None:
        """One step: the action taken and what the env returned (``observation``: the next one, the terminal
        observation at the end)."""
        self.actions.append(action)
        self.observations.append(observation)
        self.rewards.append(float(reward))
        self.terminations.append(bool(terminated))
        self.truncations.append(bool(truncated))
        self.infos.append(info)

    @property
    def total_reward(self) -> float:
        """The episode's return."""
        return float(sum(self.rewards))

    def buffer(self, episode_id: int, seed: int | None) -> Any:
        """Minari's ``EpisodeBuffer`` of the episode."""
        from minari.data_collector import EpisodeBuffer

        return EpisodeBuffer(id=episode_id, seed=seed, observations=_stack(self.observations),
                             actions=_stack(self.actions), rewards=self.rewards, terminations=self.terminations,
                             truncations=self.truncations, infos=self._kept_infos())

    def _kept_infos(self) -> dict[str, np.ndarray]:
        """The :data:`INFO_KEYS` some step reported, one value per observation (defaults where a step did not)."""
        kept: dict[str, np.ndarray] = {}
        for key in INFO_KEYS:
            values = [info.get(key) for info in self.infos]
            if all(v is None for v in values):
                continue
            if key == "violation":
                kept[key] = np.array([b"" if v is None else str(v).encode() for v in values], dtype=bytes)
            elif key == "is_success":
                kept[key] = np.array([bool(v) for v in values])
            elif key == "action_mask":
                shape = np.shape(next(v for v in values if v is not None))
                kept[key] = np.array([np.ones(shape, bool) if v is None else np.asarray(v, bool) for v in values])
            else:
                kept[key] = np.array([0.0 if v is None else float(v) for v in values], dtype=np.float64)
        return kept


def _stack(items: Sequence[Any]) -> Any:
    """Per-step items as arrays (a ``Dict`` space's: a dict of arrays)."""
    if items and isinstance(items[0], Mapping):
        return {key: _stack([item[key] for item in items]) for key in items[0]}
    return np.asarray(items)


@dataclass(frozen=True)
class DatasetInfo:
    """What :func:`write_dataset` records besides the episodes.

    :param algorithm: who acted (``random``, ``scripted``, or the run's algorithm and run dir).
    :param ref_min_score: a random policy's mean return on the env (None: unknown).
    :param ref_max_score: an expert's mean return (None: unknown; Minari keeps the scores only with it).
    :param description: one paragraph on how the episodes were recorded.
    """

    algorithm: str
    ref_min_score: float | None = None
    ref_max_score: float | None = None
    description: str = ""


def write_dataset(dataset_id: str, episodes: Sequence[EpisodeRecorder], seeds: Sequence[int | None],
                  env: str | gym.Env[Any, Any] | None, info: DatasetInfo,
                  observation_space: gym.spaces.Space[Any] | None = None,
                  action_space: gym.spaces.Space[Any] | None = None) -> Path:
    """Write ``episodes`` as the Minari dataset ``dataset_id`` under :func:`datasets_root`, atomically; its folder.

    :param env: the env's Gymnasium id (or the env) the episodes come from (Minari records its spec; None: none, the
        spaces given, e.g. a PettingZoo team's agent).
    :raises UsageError: an id that is not ``namespace/name-vN``, a dataset of that id that exists, no episodes, or
        Minari missing.
    """
    check_dataset_id(dataset_id)
    minari = require_minari()
    if not episodes:
        raise UsageError("no episodes to write (--episodes must be >= 1)")
    root = datasets_root()
    target = root / dataset_id
    if target.exists():
        raise UsageError(f"dataset {dataset_id} exists ({target}); give another id or version (-v<N+1>)")
    root.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=_STAGING, dir=root))
    before = os.environ.get("MINARI_DATASETS_PATH")
    try:
        os.environ["MINARI_DATASETS_PATH"] = str(staging)  # Minari writes under the root this variable names
        with warnings.catch_warnings():  # its advice on optional metadata (author email, code link): not ours to act on
            warnings.filterwarnings("ignore", category=UserWarning, module=r"minari\.")
            _create(
                minari, dataset_id, [e.buffer(i, s) for i, (e, s) in enumerate(zip(episodes, seeds, strict=True))],
                env, info, observation_space, action_space)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(staging / dataset_id, target)
    finally:
        if before is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = before
        with contextlib.suppress(OSError):
            shutil.rmtree(staging)
    return target


def _create(minari: Any, dataset_id: str, buffers: list[Any], env: str | gym.Env[Any, Any] | None, info: DatasetInfo,
            observation_space: gym.spaces.Space[Any] | None, action_space: gym.spaces.Space[Any] | None) -> None:
    """Minari's ``create_dataset_from_buffers`` with what :class:`DatasetInfo` records."""
    minari.create_dataset_from_buffers(
        dataset_id, buffers, env=env, eval_env=env, algorithm_name=info.algorithm, ref_min_score=info.ref_min_score,
        ref_max_score=info.ref_max_score, description=info.description or None, observation_space=observation_space,
        action_space=action_space, author="sbagents")
