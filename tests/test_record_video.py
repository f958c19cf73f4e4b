"""``python -m sbagents.record_video``: mp4 files of the right frame size, headless, and one-line errors."""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch
from cli_helpers import cli

from sbagents.api import EvalOptions, ExecOptions, OutputOptions, RunRef, TrainSpec, record_video, train

torch.set_num_threads(1)
GRID = "sbagents/GridWorld-v0"


@pytest.fixture(scope="module")
def grid_logs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One run of the book's agent (tabular Q-learning, about a second)."""
    logs = tmp_path_factory.mktemp("grid")
    train(TrainSpec("qlearning", GRID), OutputOptions(logs), EvalOptions(final_eval_episodes=0),
          ExecOptions(seed=0, verbose=0))
    return logs


def test_gridworld_video_shows_the_learned_path(grid_logs: Path, tmp_path: Path) -> None:
    out = tmp_path / "videos"
    result = cli(
        "record_video", "--algo", "qlearning", "--env", GRID, "-f", str(grid_logs), "-n", "16", "-o", str(out)
    )
    assert result.returncode == 0, result.stderr
    video = out / "qlearning-sbagents_GridWorld-v0-step-0-to-step-16.mp4"
    assert f"video: {video}" in result.stdout
    frames = iio.imread(video)
    assert frames.shape[1:] == (160, 160, 3) and frames.shape[0] >= 16
    # the greedy agent walks the optimal 8-move path twice: the picture changes between frames
    changes = [np.abs(frames[i + 1].astype(int) - frames[i].astype(int)).mean() for i in range(8)]
    assert min(changes) > 0.5


def test_default_output_folder_and_stochastic(grid_logs: Path) -> None:
    args = ["--algo", "qlearning", "--env", "GridWorld-v0", "-f", str(grid_logs), "-n", "5"]
    result = cli("record_video", *args, "--stochastic", "--seed", "1", "--exp-id", "1", "--load-best")
    assert result.returncode == 0, result.stderr
    videos = list((grid_logs / "qlearning" / "sbagents_GridWorld-v0_1" / "videos").glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 0


def test_treasure_hunt_team_video(tmp_path: Path) -> None:
    small = {"n_envs": 2, "n_steps": 256, "batch_size": 512}
    train(TrainSpec("ppo", "treasure_hunt_v0", 1536, small), OutputOptions(tmp_path),
          EvalOptions(-1, final_eval_episodes=0), ExecOptions(seed=0, verbose=0))
    path = record_video(RunRef("ppo", "treasure_hunt_v0", tmp_path), n_steps=12, output_dir=tmp_path / "v")
    frames = iio.imread(path)
    assert frames.shape[1:] == (320, 320, 3) and frames.shape[0] >= 12


def test_errors_are_one_line_exit_2(tmp_path: Path) -> None:
    no_run = cli("record_video", "--algo", "qlearning", "--env", GRID, "-f", str(tmp_path))
    assert (
        no_run.returncode == 2
        and no_run.stderr.strip().count("\n") == 0
        and "no qlearning run" in no_run.stderr
    )
    bad_n = cli("record_video", "--algo", "qlearning", "--env", GRID, "-f", str(tmp_path), "-n", "0")
    assert bad_n.returncode == 2 and "n-steps" in bad_n.stderr
    both = cli("record_video", "--algo", "qlearning", "--env", GRID, "--deterministic", "--stochastic")
    assert both.returncode == 2 and both.stderr.strip().count("\n") == 0
