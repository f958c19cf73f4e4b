"""Replay buffers kept with a run (``--save-replay-buffer``), so that ``-i`` continues an off-policy run where it
stopped instead of refilling an empty buffer (the RL Zoo's convention, in a file of numbers:
``replay_buffer.npz`` beside the model, see :mod:`sbagents.state_files`).

The run dir holds one file, the latest buffer: each checkpoint (``--save-freq``) and the final save (also after
Ctrl-C) replace it atomically, so a save cut short leaves the previous buffer intact. The file records the model's
step count, so ``-i`` continues with it only a model saved at that same step (the final model, normally); ``-i`` of
an earlier checkpoint or of ``best_model.zip`` starts with an empty buffer and says so in one warning line.
"""

from __future__ import annotations

import re
from pathlib import Path

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from sbagents.core.run_dir import CHECKPOINT_PREFIX
from sbagents.state_files import REPLAY_BUFFER_FILE, existing, replay_buffer_steps
from sbagents.state_files import load_replay_buffer as load_buffer_file
from sbagents.state_files import save_replay_buffer as save_buffer_file

__all__ = ["REPLAY_BUFFER_FILE", "ReplayBufferCheckpoint", "buffer_for", "load_replay_buffer", "save_replay_buffer"]


def save_replay_buffer(model: BaseAlgorithm, run_dir: Path) -> Path | None:
    """Write ``model``'s replay buffer to ``run_dir/replay_buffer.npz`` (atomically); None for on-policy models."""
    if not isinstance(model, OffPolicyAlgorithm) or model.replay_buffer is None:
        return None
    return save_buffer_file(model.replay_buffer, run_dir / REPLAY_BUFFER_FILE, model.num_timesteps)


def checkpoint_steps(path: Path) -> int | None:
    """The step count in a checkpoint's name (``rl_model_<N>_steps.zip``, ``--save-freq``), else None."""
    match = re.fullmatch(rf"{CHECKPOINT_PREFIX}_(\d+)_steps\.zip", path.name)
    return int(match.group(1)) if match else None


def buffer_for(model: BaseAlgorithm, trained_agent: Path) -> tuple[Path | None, str | None]:
    """The replay buffer file saved with ``trained_agent`` (the model loaded from it is ``model``), or None and why
    it has none to say (None: nothing to say: an on-policy model, or a final model of a run that kept no buffer).

    The run dir's ``replay_buffer.npz`` belongs to the model of the step it was saved at (the final model): a
    checkpoint or ``best_model.zip`` of another step has none.
    """
    if not isinstance(model, OffPolicyAlgorithm) or model.replay_buffer is None:
        return None, None
    path = existing(trained_agent.parent / REPLAY_BUFFER_FILE)
    checkpoint = checkpoint_steps(trained_agent)
    empty = "continuing with an empty replay buffer"
    if path is None:
        if checkpoint is None:
            return None, None
        return None, (f"{trained_agent.name} has no replay buffer saved with it (train with --save-replay-buffer "
                      f"to keep one); {empty}")
    saved_at = replay_buffer_steps(path)
    if saved_at is None and checkpoint is not None:
        return None, (f"{path.name} beside {trained_agent.name} does not record the step it was saved at, so it may "
                      f"not be this checkpoint's (step {checkpoint}); {empty}")
    if saved_at is not None and saved_at != model.num_timesteps:
        return None, (f"{path.name} beside {trained_agent.name} was saved at step {saved_at}, this model at step "
                      f"{model.num_timesteps}: it is not this model's buffer; {empty}")
    return path, None


def load_replay_buffer(model: BaseAlgorithm, trained_agent: Path, trust: bool = False) -> int | None:
    """Load the replay buffer saved with ``trained_agent`` (:func:`buffer_for`) into ``model``; the number of
    transitions it holds, or None when it has none (or the model is on-policy). A legacy ``replay_buffer.pkl``
    loads only with ``trust``.
    """
    path, _ = buffer_for(model, trained_agent)
    if path is None or not isinstance(model, OffPolicyAlgorithm) or model.replay_buffer is None:
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
