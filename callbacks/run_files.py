"""SB3's evaluation and checkpoint callbacks, writing their files into the run dir atomically.

SB3's ``EvalCallback`` (and sb3-contrib's ``MaskableEvalCallback``) write ``evaluations.npz`` and
``best_model.zip`` in place, and ``CheckpointCallback`` writes ``rl_model_<N>_steps.zip`` and a pickled
``VecNormalize``: a process killed mid-write leaves a truncated file that looks complete. Here every file is
written under a temporary name and renamed into place (:mod:`sbagents.atomic`), and checkpointed statistics are
``.npz`` (:mod:`sbagents.state_files`), written before the model zip so a checkpoint that exists always has them.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import CheckpointCallback, EvalCallback

from sbagents.atomic import save_model
from sbagents.state_files import BEST_VECNORMALIZE_FILE, save_vecnormalize

#: Hidden staging folders inside the run dir (never read by anything; removed when training ends), made by
#: ``tempfile.mkdtemp``: their names are unpredictable, so a run dir shipped with symlinks cannot redirect a write.
_STAGED_EVALUATIONS = ".evaluations."
_STAGED_BEST = ".best_model."
_STAGED_SUFFIX = ".partial"


class AtomicEvalOutputs:
    """Mixin for SB3 ``EvalCallback`` classes (put it before them): the parent's own ``_on_step`` evaluates (SB3's
    ``evaluate_policy``, which carries a recurrent policy's state and, in sb3-contrib's ``MaskableEvalCallback``,
    the legal-action masks) and writes ``evaluations.npz`` and ``best_model.zip`` under hidden staging names; after
    each call they are renamed to their real names, so a reader (``plot``, the dashboard, ``evaluate --load-best``)
    never sees a half-written file, and a new best model is published after the ``VecNormalize`` statistics of its
    moment (``vecnormalize_best.npz``: those of the same call, which the training env has not updated since)."""

    log_path: str | None
    best_model_save_path: str | None
    model: Any

    _final_log: Path | None
    _final_best: Path | None
    _staged_log: Path | None
    _staged_best: Path | None

    def _init_callback(self) -> None:
        if hasattr(self, "_final_log"):  # a second learn() on the same callback: already staged
            super()._init_callback()  # type: ignore[misc]
            return
        self._final_log = Path(self.log_path + ".npz") if self.log_path is not None else None
        self._final_best = Path(self.best_model_save_path) if self.best_model_save_path is not None else None
        self._staged_log = self._staged_best = None
        if self._final_log is not None:
            self._final_log.parent.mkdir(parents=True, exist_ok=True)
            self._staged_log = Path(tempfile.mkdtemp(prefix=_STAGED_EVALUATIONS, suffix=_STAGED_SUFFIX,
                                                     dir=self._final_log.parent))
            self.log_path = str(self._staged_log / "evaluations")  # np.savez adds ".npz"
        if self._final_best is not None:
            self._final_best.mkdir(parents=True, exist_ok=True)
            self._staged_best = Path(tempfile.mkdtemp(prefix=_STAGED_BEST, suffix=_STAGED_SUFFIX,
                                                      dir=self._final_best))
            self.best_model_save_path = str(self._staged_best)
        super()._init_callback()  # type: ignore[misc]

    def _on_step(self) -> bool:
        result: bool = super()._on_step()  # type: ignore[misc]
        self._publish()
        return result

    def _publish(self) -> None:
        if self._final_log is not None and self._staged_log is not None:
            staged = self._staged_log / "evaluations.npz"
            if staged.exists():
                os.replace(staged, self._final_log)
        if self._final_best is not None and self._staged_best is not None:
            staged = self._staged_best / "best_model.zip"
            if staged.exists():  # a new best this call: its statistics first, so a best model has them beside it
                venv = self.model.get_vec_normalize_env()
                if venv is not None:
                    save_vecnormalize(venv, self._final_best / BEST_VECNORMALIZE_FILE)
                os.replace(staged, self._final_best / "best_model.zip")

    def _on_training_end(self) -> None:
        self._publish()
        for staging in (self._staged_log, self._staged_best):
            if staging is not None:
                with contextlib.suppress(OSError):
                    shutil.rmtree(staging)
        super()._on_training_end()  # type: ignore[misc]


class AtomicEvalCallback(AtomicEvalOutputs, EvalCallback):
    """SB3's ``EvalCallback`` (same arguments) with atomic ``evaluations.npz`` and ``best_model.zip`` and the best
    model's ``vecnormalize_best.npz``."""


class AtomicCheckpointCallback(CheckpointCallback):
    """SB3's ``CheckpointCallback`` (same arguments) writing ``<prefix>_<N>_steps.zip`` atomically, after the
    ``VecNormalize`` statistics of the same step (``<prefix>_vecnormalize_<N>_steps.npz``, when
    ``save_vecnormalize`` and the model normalizes). Replay buffers are kept by
    :class:`sbagents.replay.buffer_files.ReplayBufferCheckpoint` (one file, not one per checkpoint)."""

    def _on_step(self) -> bool:
        if self.n_calls % self.save_freq == 0:
            venv: Any = self.model.get_vec_normalize_env()
            if self.save_vecnormalize and venv is not None:
                save_vecnormalize(venv, self._checkpoint_path("vecnormalize_", extension="npz"))
            save_model(self.model, self._checkpoint_path(extension="zip"))
        return True
