"""Replay buffers kept with a run (``--save-replay-buffer``), so that ``-i`` continues an off-policy run where it
stopped instead of refilling an empty buffer (the RL Zoo's convention: ``replay_buffer.pkl`` beside the model).

The run dir holds one file, the latest buffer: each checkpoint (``--save-freq``) and the final save (also after
Ctrl-C) replace it atomically, so a save cut short leaves the previous buffer intact.
"""

from __future__ import annotations

import os
from pathlib import Path

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

#: File name of the buffer in a run dir (and beside a model given to ``-i``).
REPLAY_BUFFER_FILE = "replay_buffer.pkl"


def save_replay_buffer(model: BaseAlgorithm, run_dir: Path) -> Path | None:
    """Write ``model``'s replay buffer to ``run_dir/replay_buffer.pkl`` (via a temporary file); None for on-policy
    models."""
    if not isinstance(model, OffPolicyAlgorithm):
        return None
    path = run_dir / REPLAY_BUFFER_FILE
    partial = path.with_name(path.name + ".partial")
    model.save_replay_buffer(partial)
    os.replace(partial, path)
    return path


def load_replay_buffer(model: BaseAlgorithm, trained_agent: Path) -> int | None:
    """Load the ``replay_buffer.pkl`` that sits beside ``trained_agent`` into ``model``; the number of transitions
    it holds, or None when there is none (or the model is on-policy)."""
    path = trained_agent.parent / REPLAY_BUFFER_FILE
    if not isinstance(model, OffPolicyAlgorithm) or not path.is_file():
        return None
    model.load_replay_buffer(path)
    buffer = model.replay_buffer
    assert buffer is not None
    return int(buffer.size() * buffer.n_envs)


class ReplayBufferCheckpoint(BaseCallback):
    """Every ``save_freq`` calls (env steps / n_envs, as SB3's ``CheckpointCallback``), replace the run dir's
    ``replay_buffer.pkl`` with the current buffer.

    :param run_dir: the run dir.
    :param save_freq: callback calls between saves.
    """

    def __init__(self, run_dir: Path, save_freq: int) -> None:
        super().__init__()
        self.run_dir, self.save_freq = run_dir, save_freq

    def _on_step(self) -> bool:
        if self.n_calls % self.save_freq == 0:
            save_replay_buffer(self.model, self.run_dir)
        return True
