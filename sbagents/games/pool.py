"""Self-play opponents: the learner's past snapshots in the run dir, optionally mixed with fixed players.

:class:`SnapshotCallback` saves ``<run dir>/opponents/snapshot_<steps>.zip`` every ``snapshot_freq`` steps (and
one at the start); :class:`OpponentPool` draws each game's opponent from that folder: the latest snapshot, or one
uniformly among the last ``last_k``; with probability ``mix[name]`` a fixed player (``random``, ``heuristic``, ...)
instead. Snapshots are files, so self-play works the same with SubprocVecEnv workers.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from sbagents.atomic import save_model
from sbagents.core.selfplay_options import SelfPlayOptions
from sbagents.games.players import Player, load_player, snapshot_player

SNAPSHOT_DIR = "opponents"
_SNAPSHOT = re.compile(r"^snapshot_(\d+)\.zip$")


def snapshots(pool_dir: str | Path) -> list[tuple[int, Path]]:
    """The snapshots in ``pool_dir`` as ``(steps, path)``, oldest first."""
    found = []
    for entry in os.scandir(pool_dir) if Path(pool_dir).is_dir() else ():
        match = _SNAPSHOT.match(entry.name)
        if match:
            found.append((int(match.group(1)), Path(entry.path)))
    return sorted(found)


class OpponentPool:
    """Draws each game's opponent (see the module docstring); ``draw(rng)`` is what :class:`SelfPlayEnv` calls."""

    def __init__(self, pool_dir: str | Path, options: SelfPlayOptions, game: str) -> None:
        self.pool_dir, self.options, self.game = Path(pool_dir), options, game
        self._fixed: dict[str, Player] = {}

    def draw(self, rng: np.random.Generator) -> Player:
        """One opponent: a fixed player with its ``mix`` share, else a snapshot (random play before the first)."""
        u = rng.random()
        for name, share in self.options.mix.items():
            if u < share:
                return self._fixed_player(name, rng)
            u -= share
        pool = snapshots(self.pool_dir)
        if not pool:
            return self._fixed_player("random", rng)
        if self.options.opponents == "latest":
            path = pool[-1][1]
        else:
            recent = pool[-self.options.last_k:]
            path = recent[int(rng.integers(len(recent)))][1]
        return snapshot_player(path, deterministic=False, rng=rng)

    def _fixed_player(self, name: str, rng: np.random.Generator) -> Player:
        if name not in self._fixed:
            self._fixed[name] = load_player(name, self.game, rng)
        player = self._fixed[name]
        if hasattr(player, "rng"):
            player.rng = rng  # the env's generator: seeded runs repeat
        return player


class SnapshotCallback(BaseCallback):
    """Saves the learner into the pool folder at the start and every ``snapshot_freq`` env steps."""

    def __init__(self, pool_dir: str | Path, snapshot_freq: int) -> None:
        super().__init__()
        self.pool_dir, self.snapshot_freq = Path(pool_dir), snapshot_freq
        self.last_saved = -1

    def _on_training_start(self) -> None:
        self.pool_dir.mkdir(parents=True, exist_ok=True)
        existing = snapshots(self.pool_dir)
        if existing:
            self.last_saved = existing[-1][0]
        else:
            self.save()

    def _on_step(self) -> bool:
        if self.num_timesteps - self.last_saved >= self.snapshot_freq:
            self.save()
        return True

    def save(self) -> Path:
        """Write ``snapshot_<steps>.zip`` atomically (workers never read a half-written file)."""
        steps = self.num_timesteps
        path = save_model(self.model, self.pool_dir / f"snapshot_{steps}.zip")
        self.last_saved = steps
        return path


class IllegalMovesCallback(BaseCallback):
    """Sums the training envs' illegal moves (``SelfPlayEnv.illegal_moves``: the learner's; 0 with masks) into
    ``total`` and TensorBoard's ``selfplay/illegal_moves`` after every rollout and at the end."""

    def __init__(self) -> None:
        super().__init__()
        self.total = 0

    def _count(self) -> None:
        self.total = int(sum(self.training_env.get_attr("illegal_moves")))
        self.logger.record("selfplay/illegal_moves", self.total)

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        self._count()

    def _on_training_end(self) -> None:
        self._count()

    def summary_items(self) -> dict[str, Any]:
        """What ``summary.json`` gains: ``illegal_moves`` during training."""
        return {"illegal_moves": self.total}
