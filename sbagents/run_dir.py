"""Run directories in RL Zoo's layout: ``<log-folder>/<algo>/<EnvId with / replaced by _>_<k>/``."""

from __future__ import annotations

import errno
import os
import re
from pathlib import Path

from sbagents.errors import UsageError

SUMMARY_FILE = "summary.json"
VECNORMALIZE_FILE = "vecnormalize.pkl"
BEST_MODEL_FILE = "best_model.zip"


def env_stem(env_id: str) -> str:
    """The file-name form of an env id: ``sbagents/GridWorld-v0`` -> ``sbagents_GridWorld-v0``."""
    return env_id.replace("/", "_").replace(":", "_")


def _existing_ids(algo_dir: Path, stem: str) -> list[int]:
    pattern = re.compile(rf"^{re.escape(stem)}_(\d+)$")
    if not algo_dir.is_dir():
        return []
    return sorted(int(m.group(1)) for p in algo_dir.iterdir() if (m := pattern.match(p.name)))


def create_run_dir(log_folder: str | Path, algo: str, env_id: str) -> Path:
    """Create and return a new run dir with k = highest existing + 1.

    ``os.mkdir`` is atomic, so two runs started at once into the same folder never share a directory:
    the loser of a race moves on to the next k.
    """
    algo_dir = Path(log_folder) / algo
    stem = env_stem(env_id)
    try:
        algo_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"log folder {log_folder} is not writable: {exc.strerror}") from None
    if not os.access(algo_dir, os.W_OK | os.X_OK):
        raise UsageError(f"log folder {log_folder} is not writable")
    k = max(_existing_ids(algo_dir, stem), default=0) + 1
    while True:
        run_dir = algo_dir / f"{stem}_{k}"
        try:
            run_dir.mkdir()
            return run_dir
        except FileExistsError:
            k += 1
        except OSError as exc:
            if exc.errno in (errno.EACCES, errno.EROFS, errno.EPERM):
                raise UsageError(f"log folder {log_folder} is not writable: {exc.strerror}") from None
            raise


def find_run_dir(log_folder: str | Path, algo: str, env_id: str, exp_id: int = 0) -> Path:
    """The run dir of experiment ``exp_id`` (0 = the latest), or :class:`UsageError` listing what exists."""
    if exp_id < 0:
        raise UsageError(f"--exp-id must be >= 0 (0: the latest run), got {exp_id}")
    algo_dir = Path(log_folder) / algo
    stem = env_stem(env_id)
    ids = _existing_ids(algo_dir, stem)
    if not ids:
        raise UsageError(f"no {algo} run for {env_id} in {log_folder} (looked for {algo_dir / stem}_<k>)")
    k = ids[-1] if exp_id == 0 else exp_id
    if k not in ids:
        raise UsageError(f"no run {stem}_{k} in {algo_dir}; existing exp ids: {', '.join(map(str, ids))}")
    return algo_dir / f"{stem}_{k}"


def model_path(run_dir: Path, env_id: str, load_best: bool = False) -> Path:
    """The final (or best) model file of a run, or :class:`UsageError` if it is missing."""
    path = run_dir / (BEST_MODEL_FILE if load_best else f"{env_stem(env_id)}.zip")
    if not path.exists():
        hint = " (no evaluation ran during training; drop --load-best)" if load_best else ""
        raise UsageError(f"model file {path} does not exist{hint}")
    return path
