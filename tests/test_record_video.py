"""``python -m sbagents.record_video``: mp4 files of the right frame size, headless, their decisions sidecars,
and one-line errors."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import gymnasium as gym
import imageio.v3 as iio
import numpy as np
import pytest
import torch
from cli_helpers import cli
from stable_baselines3.common.vec_env import DummyVecEnv

import sbagents.registration  # noqa: F401  (registers the sbagents/ env ids)
from sbagents.api import EvalOptions, ExecOptions, OutputOptions, RunRef, TrainSpec, record_video, train
from sbagents.visualize.video import _DecisionLog, sidecar_path

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
    assert result.stdout.strip().splitlines()[-1] == f"decisions: {video.with_suffix('.csv')}"
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


@pytest.mark.filterwarnings("ignore:.*Unable to save last video")  # SB3's recorder, after the failed write
def test_video_is_renamed_into_place_and_a_failed_write_leaves_nothing(grid_logs: Path, tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """The mp4 is written to a hidden temporary name and renamed; a write that fails midway (here after half a
    file) leaves neither a truncated video nor the temporary file, and an older video at that path stays."""
    from moviepy.video.io.ImageSequenceClip import ImageSequenceClip

    out = tmp_path / "videos"
    args = ["--algo", "qlearning", "--env", GRID, "-f", str(grid_logs), "-n", "4", "-o", str(out)]
    assert cli("record_video", *args).returncode == 0
    (video,) = out.glob("*.mp4")
    before = video.read_bytes()
    written: list[str] = []

    def half_then_fail(self: Any, filename: str, *a: Any, **k: Any) -> None:
        written.append(filename)
        Path(filename).write_bytes(before[: len(before) // 2])
        raise OSError("disk went away")

    monkeypatch.setattr(ImageSequenceClip, "write_videofile", half_then_fail)
    assert cli("record_video", *args).returncode != 0
    assert Path(written[0]).parent == out and Path(written[0]).name.startswith(".") and written[0] != str(video)
    assert sorted(p.name for p in out.iterdir()) == sorted([video.name, video.with_suffix(".csv").name])
    assert video.read_bytes() == before


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_gridworld_sidecar_matches_the_frames_and_a_replay(grid_logs: Path, tmp_path: Path) -> None:
    """Row t: the state of frame t, the action taken in it, the env's reward; counters restart after the goal."""
    video = record_video(RunRef("qlearning", GRID, grid_logs), n_steps=12, output_dir=tmp_path)
    rows = _rows(sidecar_path(video))
    assert sidecar_path(video) == video.with_suffix(".csv")
    assert list(rows[0]) == ["frame", "episode", "step", "cell", "move", "reward", "terminated", "truncated",
                             "violation", "cost"]
    assert [int(r["frame"]) for r in rows] == list(range(12))
    # the greedy agent reaches the goal in 8 moves: episode 0 is rows 0-7, then a new episode starts at step 0
    assert [(int(r["episode"]), int(r["step"])) for r in rows] == [(0, t) for t in range(8)] + [(1, t) for t in
                                                                                              range(4)]
    assert [r["terminated"] for r in rows] == ["False"] * 7 + ["True"] + ["False"] * 4
    assert {r["truncated"] for r in rows} == {"False"} and {(r["violation"], r["cost"]) for r in rows} == {("", "0")}
    frames = iio.imread(video).astype(int)
    assert len(frames) == 13
    env = gym.make(GRID, render_mode="rgb_array")
    obs, _ = env.reset(seed=0)
    returns = [0.0, 0.0]
    for t, row in enumerate(rows):
        state = env.render().astype(int)
        errors = [np.abs(frames[k] - state).mean() for k in (t - 1, t, t + 1) if k >= 0]
        assert int(row["cell"]) == obs and errors[-2] < 2 < min(errors[:-2] + errors[-1:])  # frame t shows it
        obs, reward, terminated, truncated, _ = env.step(int(row["move"]))
        assert float(row["reward"]) == reward and row["terminated"] == str(terminated)
        returns[int(row["episode"])] += float(row["reward"])
        if terminated or truncated:
            obs, _ = env.reset()  # the frame after the goal step shows the next episode's reset state
            assert np.abs(frames[t + 1] - env.render().astype(int)).mean() < 2
    assert returns[0] == 93.0  # 7 moves at -1, the goal at +100: the episode return


class _Violations(gym.Wrapper[Any, Any, Any, Any]):
    """GridWorld whose obstacle hits are safety violations (walls: a cost without a name)."""

    def step(self, action: Any) -> Any:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if info["event"] == "obstacle":
            info["violation"] = "obstacle"
        elif info["event"] == "wall":
            info["cost"] = 0.5
        return obs, reward, terminated, truncated, info


def test_sidecar_violations_and_truncation(tmp_path: Path) -> None:
    venv = DummyVecEnv([lambda: _Violations(gym.make(GRID, max_steps=3))])
    log = _DecisionLog(venv)
    log.observe(venv.reset())
    for action in (0, 1, 3, 1, 1):  # wall, down, obstacle (truncated at step 3), down, right (new episode)
        obs, rewards, dones, infos = venv.step(np.array([action]))
        log.record(np.array([action]), rewards, dones, infos)
        log.observe(obs)
    log.write(tmp_path / "d.csv")
    rows = _rows(tmp_path / "d.csv")
    assert [(r["episode"], r["step"], r["cell"], r["move"]) for r in rows] == [
        ("0", "0", "0", "0"), ("0", "1", "0", "1"), ("0", "2", "5", "3"), ("1", "0", "0", "1"), ("1", "1", "5", "1")]
    assert [(r["violation"], r["cost"]) for r in rows] == [("cost", "0.5"), ("", "0"), ("obstacle", "1"), ("", "0"),
                                                           ("", "0")]
    assert [(r["terminated"], r["truncated"]) for r in rows][2] == ("False", "True")
    assert [float(r["reward"]) for r in rows] == [-1, -1, -10, -1, -1]


def test_smart_home_sidecar_is_unnormalized(tmp_path: Path) -> None:
    """A VecNormalize run: the sidecar has the env's own observations and rewards (a replay gives the same)."""
    small = {"n_envs": 1, "n_steps": 128, "batch_size": 128, "n_epochs": 1}
    train(TrainSpec("ppo", "sbagents/SmartHome-v0", 128, small), OutputOptions(tmp_path),
          EvalOptions(eval_freq=-1, final_eval_episodes=0), ExecOptions(seed=0, verbose=0))
    assert list(tmp_path.glob("ppo/*/vecnormalize.npz"))
    video = record_video(RunRef("ppo", "sbagents/SmartHome-v0", tmp_path), n_steps=102, output_dir=tmp_path / "v")
    rows = _rows(sidecar_path(video))
    names = ["Temperature", "Light_Level", "Time", "Preferred_Temp", "Preferred_Light"]
    assert list(rows[0])[3:10] == [*names, "Action_Temp", "Action_Light"] and len(rows) == 102
    assert [(r["episode"], r["step"]) for r in rows[99:]] == [("0", "99"), ("1", "0"), ("1", "1")]
    assert rows[99]["truncated"] == "True" and rows[99]["terminated"] == "False"
    env = gym.make("sbagents/SmartHome-v0")
    obs, _ = env.reset(seed=0)
    returns = [0.0, 0.0]
    for row in rows:
        np.testing.assert_allclose([float(row[n]) for n in names], obs, rtol=1e-5)
        action = np.array([float(row["Action_Temp"]), float(row["Action_Light"])], dtype=np.float32)
        obs, reward, _, truncated, _ = env.step(action)
        assert float(row["reward"]) == pytest.approx(reward, rel=1e-5, abs=1e-5)
        returns[int(row["episode"])] += float(reward)
        if truncated:
            obs, _ = env.reset()
    assert sum(float(r["reward"]) for r in rows[:100]) == pytest.approx(returns[0], rel=1e-5)


def test_treasure_hunt_team_video(tmp_path: Path) -> None:
    small = {"n_envs": 2, "n_steps": 256, "batch_size": 512}
    train(TrainSpec("ppo", "treasure_hunt_v0", 512, small), OutputOptions(tmp_path),  # one rollout: plumbing
          EvalOptions(eval_freq=-1, final_eval_episodes=0), ExecOptions(seed=0, verbose=0))
    path = record_video(RunRef("ppo", "treasure_hunt_v0", tmp_path), n_steps=12, output_dir=tmp_path / "v")
    frames = iio.imread(path)
    assert frames.shape[1:] == (320, 320, 3) and frames.shape[0] >= 12
    assert not sidecar_path(path).exists()  # PettingZoo runs get no sidecar


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
