"""Saving and reloading what a run needs to be evaluated, exported or continued."""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from stable_baselines3.common.base_class import BaseAlgorithm

from sbagents.config import load_yaml
from sbagents.errors import UsageError
from sbagents.hyperparams import Experiment, resolve
from sbagents.run_dir import VECNORMALIZE_FILE, env_stem, find_run_dir, model_path


def config_path(run_dir: Path, env_id: str) -> Path:
    """``<run dir>/<EnvId>/config.yml`` (RL Zoo layout)."""
    return run_dir / env_stem(env_id) / "config.yml"


def save_run_config(
    run_dir: Path, env_id: str, hyperparams: dict[str, Any], args: dict[str, Any], command: str
) -> None:
    """Write ``config.yml`` (the resolved hyperparameters), ``args.yml`` and ``command.txt`` (any backend)."""
    folder = config_path(run_dir, env_id).parent
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "config.yml").write_text(yaml.safe_dump(hyperparams, sort_keys=True))
    (folder / "args.yml").write_text(yaml.safe_dump(args, sort_keys=True))
    (run_dir / "command.txt").write_text(command + "\n")


def save_experiment(run_dir: Path, exp: Experiment, args: dict[str, Any], command: str) -> None:
    """:func:`save_run_config` of an SB3 :class:`Experiment`."""
    save_run_config(run_dir, exp.env_id, exp.hyperparams, args, command)


def load_run_config(run_dir: Path, env_id: str) -> dict[str, Any]:
    """The hyperparameters saved in a run's ``config.yml``, or :class:`UsageError` if the file is missing."""
    path = config_path(run_dir, env_id)
    if not path.exists():
        raise UsageError(f"{run_dir} has no {path.relative_to(run_dir)}; is it a sbagents run dir?")
    return load_yaml(path) or {}


def load_experiment(run_dir: Path, algo: str, env_id: str) -> Experiment:
    """The :class:`Experiment` a run was trained with (so evaluation wraps the env identically)."""
    return resolve(algo, env_id, load_run_config(run_dir, env_id), str(config_path(run_dir, env_id)))


def check_model_file(path: str | Path) -> Path:
    """Raise :class:`UsageError` unless ``path`` is an SB3 model zip (a zip holding ``data``)."""
    path = Path(path)
    if not path.exists():
        raise UsageError(f"--trained-agent {path} does not exist")
    try:
        with zipfile.ZipFile(path) as archive:
            if "data" not in archive.namelist():
                raise UsageError(f"--trained-agent {path} is a zip file but not an SB3 model (no 'data' entry)")
    except zipfile.BadZipFile:
        raise UsageError(f"--trained-agent {path} is not an SB3 model file (not a zip archive)") from None
    return path


@dataclass
class LoadedRun:
    """A finished run, ready to evaluate or export."""

    run_dir: Path
    model_path: Path
    experiment: Experiment
    model: BaseAlgorithm

    @property
    def stats_path(self) -> Path:
        """Where the run's ``VecNormalize`` statistics are (the file may not exist)."""
        return self.run_dir / VECNORMALIZE_FILE


def load_run(
    algo: str, env_id: str, log_folder: str | Path = "logs", exp_id: int = 0, load_best: bool = False
) -> LoadedRun:
    """Find run ``exp_id`` (0 = latest) of ``algo`` on ``env_id`` and load its model and experiment."""
    from sbagents.algos import ALGOS

    if algo not in ALGOS:
        raise UsageError(f"unknown algo {algo!r}; available: {', '.join(ALGOS)}")
    run_dir = find_run_dir(log_folder, algo, env_id, exp_id)
    path = model_path(run_dir, env_id, load_best)
    exp = load_experiment(run_dir, algo, env_id)
    return LoadedRun(run_dir, path, exp, ALGOS[algo].cls.load(str(path), device="cpu"))
