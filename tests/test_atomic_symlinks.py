"""A run dir from elsewhere may hold symlinks: at the temporary names older sbagents wrote to
(``.<name>.<pid>.partial``) and at final names. No writer follows them: temporary files are new files with
unpredictable names (``mkstemp``), and the rename into place replaces a symlink at the final name."""

from __future__ import annotations

import os
import shutil
import stat
from pathlib import Path

import numpy as np
import pytest

from sbagents.atomic import (
    replace_dir,
    staging_dir,
    temporary_name,
    write_bytes,
    write_csv,
    write_json,
    write_npz,
    write_text,
    write_with,
)

#: pids an older sbagents' temporary names may carry: this process's, its neighbours', and low ones.
PIDS = sorted({os.getpid(), os.getpid() + 1, os.getpid() - 1, 1, 2, 100})


def plant(folder: Path, name: str, outside: Path, suffixes: tuple[str, ...] = (".partial",)) -> dict[Path, bytes]:
    """Symlinks at ``name`` and at every old predictable temporary name of it, each to its own file in
    ``outside``; returns those files with their content."""
    victims: dict[Path, bytes] = {}
    links = [name] + [f".{name}.{pid}{suffix}" for pid in PIDS for suffix in suffixes]
    for i, link in enumerate(links):
        victim = outside / f"victim_{i}"
        victim.write_bytes(f"outside {i}".encode())
        (folder / link).symlink_to(victim)
        victims[victim] = victim.read_bytes()
    return victims


def assert_untouched(victims: dict[Path, bytes]) -> None:
    for victim, content in victims.items():
        assert victim.read_bytes() == content, victim


def assert_regular(path: Path) -> None:
    mode = os.lstat(path).st_mode
    assert stat.S_ISREG(mode) and not path.is_symlink(), path


@pytest.fixture
def dirs(tmp_path: Path) -> tuple[Path, Path]:
    run, outside = tmp_path / "run", tmp_path / "outside"
    run.mkdir()
    outside.mkdir()
    return run, outside


WRITERS = {
    "summary.json": lambda p: write_json(p, {"new": 1}),
    "notes.txt": lambda p: write_text(p, "new text"),
    "model.bin": lambda p: write_bytes(p, b"new bytes"),
    "table.csv": lambda p: write_csv(p, ["a"], [{"a": 1}]),
    "stats.npz": lambda p: write_npz(p, x=np.arange(3)),
    "copy.zip": lambda p: write_with(p, lambda tmp: tmp.write_bytes(b"written by path")),
}


@pytest.mark.parametrize("name", list(WRITERS))
def test_writers_replace_planted_symlinks_and_follow_none(dirs: tuple[Path, Path], name: str) -> None:
    run, outside = dirs
    victims = plant(run, name, outside)
    WRITERS[name](run / name)
    assert_untouched(victims)
    final = run / name
    assert_regular(final)
    if name.endswith(".npz"):
        with np.load(final, allow_pickle=False) as data:
            assert data["x"].tolist() == [0, 1, 2]
    else:
        assert final.read_bytes() in (b'{\n  "new": 1\n}\n', b"new text", b"new bytes", b"a\r\n1\r\n",
                                      b"written by path")
    # nothing new beside the final file: the planted temporary-name symlinks are left as they were
    assert sorted(p.name for p in run.iterdir()) == sorted([name] + [f".{name}.{pid}.partial" for pid in PIDS])


def test_a_failed_write_leaves_the_symlink_alone_and_the_outside_file_unchanged(dirs: tuple[Path, Path]) -> None:
    run, outside = dirs
    victims = plant(run, "summary.json", outside)

    def fail(tmp: Path) -> None:
        tmp.write_bytes(b"half")
        raise RuntimeError("cut short")

    with pytest.raises(RuntimeError):
        write_with(run / "summary.json", fail)
    assert_untouched(victims)
    assert (run / "summary.json").is_symlink()  # nothing was replaced


def test_temporary_names_are_fresh_regular_files_with_unpredictable_names(tmp_path: Path) -> None:
    target = tmp_path / "best_model.zip"
    first, second = temporary_name(target), temporary_name(target, ".partial.mp4")
    try:
        assert first != second and first.parent == second.parent == tmp_path
        assert first.name.startswith(".best_model.zip.") and first.name.endswith(".partial")
        assert second.name.endswith(".partial.mp4") and str(os.getpid()) not in first.name.split(".")
        for tmp in (first, second):
            assert_regular(tmp)
            assert tmp.stat().st_size == 0
        umask = os.umask(0o022)
        os.umask(umask)
        assert stat.S_IMODE(first.stat().st_mode) == 0o666 & ~umask  # as a plain open() would make it
    finally:
        first.unlink()
        second.unlink()


def test_a_folder_is_published_over_a_planted_symlink(dirs: tuple[Path, Path]) -> None:
    run, outside = dirs
    (outside / "keep.txt").write_text("outside")
    (run / "rllib_checkpoint").symlink_to(outside, target_is_directory=True)
    for version in ("one", "two"):
        staged = staging_dir(run / "rllib_checkpoint")
        assert staged.parent == run and staged.name.startswith(".rllib_checkpoint.")
        (staged / "state.txt").write_text(version)
        replace_dir(staged, run / "rllib_checkpoint")
        assert not (run / "rllib_checkpoint").is_symlink()
        assert (run / "rllib_checkpoint" / "state.txt").read_text() == version
    assert sorted(p.name for p in run.iterdir()) == ["rllib_checkpoint"]  # no staging or old folder left
    assert sorted(p.name for p in outside.iterdir()) == ["keep.txt"]


def test_eval_callback_staging_ignores_symlinks_at_the_old_staging_names(dirs: tuple[Path, Path]) -> None:
    """``evaluations.npz`` and ``best_model.zip`` are staged in new hidden folders, not at the fixed names
    ``.evaluations.partial.npz`` / ``.best_model.partial/`` an older sbagents used."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env

    import sbagents.registration  # noqa: F401  (registers sbagents/GridWorld-v0)
    from sbagents.callbacks.run_files import AtomicEvalCallback

    torch.set_num_threads(1)
    run, outside = dirs
    victims = plant(run, "evaluations.npz", outside)
    (outside / "best").mkdir()
    (run / ".evaluations.partial.npz").symlink_to(outside / "evaluations.npz")
    (run / ".best_model.partial").symlink_to(outside / "best", target_is_directory=True)
    (run / "best_model.zip").symlink_to(outside / "victim_0")
    env = make_vec_env("sbagents/GridWorld-v0", n_envs=1, seed=0)
    eval_env = make_vec_env("sbagents/GridWorld-v0", n_envs=1, seed=1)
    callback = AtomicEvalCallback(eval_env, eval_freq=32, n_eval_episodes=1, best_model_save_path=str(run),
                                  log_path=str(run), verbose=0)  # SB3 writes <log_path>/evaluations.npz
    PPO("MlpPolicy", env, n_steps=32, batch_size=32, n_epochs=1, seed=0, verbose=0).learn(64, callback=callback)
    assert_untouched(victims)
    assert not (outside / "evaluations.npz").exists() and not list((outside / "best").iterdir())
    for name in ("evaluations.npz", "best_model.zip"):
        assert_regular(run / name)
    with np.load(run / "evaluations.npz", allow_pickle=False) as data:
        assert data["timesteps"].tolist() == [32, 64]
    assert not [p.name for p in run.iterdir() if p.name.startswith(".") and not p.is_symlink()]


def test_record_video_writes_no_file_outside_the_run_dir(tmp_path: Path) -> None:
    """``record_video`` into a run dir shipped with symlinks at the old temporary names of the mp4 and of its
    decisions sidecar, and at their final names: both outputs become regular files, the targets are unchanged."""
    import torch

    from sbagents.api import EvalOptions, ExecOptions, OutputOptions, RunRef, TrainSpec, record_video, train

    torch.set_num_threads(1)
    logs, outside = tmp_path / "logs", tmp_path / "outside"
    outside.mkdir()
    train(TrainSpec("qlearning", "sbagents/GridWorld-v0"), OutputOptions(logs), EvalOptions(final_eval_episodes=0),
          ExecOptions(seed=0, verbose=0))
    (run_dir,) = (logs / "qlearning").iterdir()
    videos = run_dir / "videos"
    videos.mkdir()
    stem = "qlearning-sbagents_GridWorld-v0-step-0-to-step-4"
    victims = plant(videos, f"{stem}.mp4", outside, (".partial.mp4", ".partial"))
    (outside / "csv").mkdir()
    victims |= plant(videos, f"{stem}.csv", outside / "csv")
    video = record_video(RunRef("qlearning", "sbagents/GridWorld-v0", logs), n_steps=4)
    assert video == videos / f"{stem}.mp4"
    assert_untouched(victims)
    for path in (video, video.with_suffix(".csv")):
        assert_regular(path)
    assert video.read_bytes()[4:8] == b"ftyp"  # an mp4
    assert video.with_suffix(".csv").read_text().startswith("frame,episode,step,")
    shutil.rmtree(videos)
    videos.symlink_to(outside, target_is_directory=True)  # the videos folder itself leads out
    before = sorted(p.name for p in outside.iterdir())
    from sbagents.errors import UsageError

    with pytest.raises(UsageError, match="symlink"):
        record_video(RunRef("qlearning", "sbagents/GridWorld-v0", logs), n_steps=4)
    assert sorted(p.name for p in outside.iterdir()) == before


def test_a_default_output_folder_that_is_a_symlink_is_refused(dirs: tuple[Path, Path]) -> None:
    from sbagents.atomic import run_subfolder
    from sbagents.errors import UsageError

    run_dir, outside = dirs
    (run_dir / "export").symlink_to(outside, target_is_directory=True)
    with pytest.raises(UsageError, match="symlink"):
        run_subfolder(run_dir, "export", create=False)
    assert run_subfolder(run_dir, "videos") == run_dir / "videos" and (run_dir / "videos").is_dir()
    assert not (run_dir / "export_checkpoint_5").exists()
    assert run_subfolder(run_dir, "export_checkpoint_5", create=False) == run_dir / "export_checkpoint_5"
