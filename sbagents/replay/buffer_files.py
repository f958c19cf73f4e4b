"""Replay buffers kept with a run (``--save-replay-buffer``), so that ``-i`` continues an off-policy run where it
stopped instead of refilling an empty buffer (the RL Zoo's convention, in a file of numbers:
``replay_buffer.npz`` beside the model, see :mod:`sbagents.state_files`).

The run dir holds one file, the latest buffer: each checkpoint (``--save-freq``) and the final save (also after
Ctrl-C) replace it atomically, so a save cut short leaves the previous buffer intact.
"""

from __future__ import annotations

from pathlib import Path

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from sbagents.state_files import REPLAY_BUFFER_FILE, existing
from sbagents.state_files import load_replay_buffer as load_buffer_file
from sbagents.state_files import save_replay_buffer as save_buffer_file

__all__ = ["REPLAY_BUFFER_FILE", "ReplayBufferCheckpoint", "load_replay_buffer", "save_replay_buffer"]


def save_replay_buffer(model: BaseAlgorithm, run_dir: Path) -> Path | None:
    """Write ``model``'s replay buffer to ``run_dir/replay_buffer.npz`` (atomically); None for on-policy models."""
    if not isinstance(model, OffPolicyAlgorithm) or model.replay_buffer is None:
        return None
    return save_buffer_file(model.replay_buffer, run_dir / REPLAY_BUFFER_FILE)


def load_replay_buffer(model: BaseAlgorithm, trained_agent: Path, trust: bool = False) -> int | None:
    """Load the replay buffer saved beside ``trained_agent`` into ``model``; the number of transitions it holds, or
    None when there is none (or the model is on-policy). A legacy ``replay_buffer.pkl`` loads only with ``trust``.
    """
    path = existing(trained_agent.parent / REPLAY_BUFFER_FILE)
    if not isinstance(model, OffPolicyAlgorithm) or path is None or model.replay_buffer is None:
        return None
    load_buffer_file(model.replay_buffer, path, trust, model)
    buffer = model.replay_buffer
    assert buffer is not None
    return int(buffer.size() * buffer.n_envs)


class ReplayBufferCheckpoint(BaseCallback):
    """Every ``save_freq`` calls (env steps / n_envs, as SB3's ``CheckpointCallback``), replace the run dir's
    ``replay_buffer.npz`` with the current buffer.

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
