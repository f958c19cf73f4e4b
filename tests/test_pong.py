"""Pong through the CLI: the zoo's ``atari`` entry, identical wrapping in evaluation, full-game scores, video.

One short DQN run (1,000 steps, learning from step 900, a 5,000-transition buffer: plumbing, not learning) is
shared by the tests of this module; long training belongs in ``benchmarks/speed/pong_throughput.py``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import imageio.v3 as iio
import pytest
import torch
import yaml
from cli_helpers import cli, last_json, summary
from stable_baselines3.common.atari_wrappers import AtariWrapper
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import VecFrameStack

from sbagents.core.env_names import resolve_env
from sbagents.core.run_dir import load_experiment
from sbagents.env_factory import make_vec

PONG = "PongNoFrameskip-v4"
torch.set_num_threads(1)


@pytest.fixture(scope="module")
def pong_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    logs = tmp_path_factory.mktemp("pong")
    result = cli(
        "train",
        "--algo",
        "dqn",
        "--env",
        PONG,
        "-f",
        str(logs),
        "-n",
        "1000",
        "--seed",
        "0",
        "-params",
        "buffer_size:5000",
        "learning_starts:900",
        "--eval-freq",
        "-1",
        "--final-eval-episodes",
        "1",
        "--verbose",
        "0",
    )
    assert result.returncode == 0, result.stderr
    return logs


def test_train_uses_the_atari_recipe(pong_run: Path) -> None:
    run_dir = pong_run / "dqn" / f"{PONG}_1"
    config = yaml.safe_load((run_dir / PONG / "config.yml").read_text())
    assert config["env_wrapper"] == ["stable_baselines3.common.atari_wrappers.AtariWrapper"]
    assert config["frame_stack"] == 4 and config["policy"] == "CnnPolicy"
    assert config["optimize_memory_usage"] is True
    assert config["replay_buffer_kwargs"] == {"handle_timeout_termination": False}
    assert config["buffer_size"] == 5000 and config["learning_starts"] == 900  # -params overrides
    s = summary(run_dir)
    assert s["n_timesteps"] == 1000 and s["eval"]["n_episodes"] == 1


def test_evaluation_wraps_identically_and_scores_full_games(pong_run: Path) -> None:
    run_dir = pong_run / "dqn" / f"{PONG}_1"
    exp = load_experiment(run_dir, "dqn", PONG)
    venv = make_vec(exp, resolve_env(PONG), 1, seed=0)
    assert isinstance(venv, VecFrameStack) and venv.observation_space.shape == (84, 84, 4)
    env = venv.venv.envs[0]  # type: ignore[attr-defined]
    assert isinstance(env, AtariWrapper)
    # Monitor below AtariWrapper: it sees every frame and the unclipped rewards of the whole game
    inner: Any = env
    chain: list[type] = []
    while hasattr(inner, "env"):
        chain.append(type(inner))
        inner = inner.env
    assert Monitor in chain and chain.index(Monitor) > chain.index(AtariWrapper)
    venv.close()
    result = cli("evaluate", "--algo", "dqn", "--env", PONG, "-f", str(pong_run), "-n", "1", "--json")
    assert result.returncode == 0, result.stderr
    report = last_json(result.stdout)
    # the saved model on a fresh env, seeded as the final evaluation of training: the very same game
    final = summary(run_dir)["eval"]
    assert (report["mean_return"], report["mean_length"]) == (final["mean_return"], final["mean_length"])
    # a full game is >= 21 points; episode lengths are the Monitor's raw frames (4 per agent step)
    assert report["mean_length"] >= 21 * 50


def test_record_video_pong(pong_run: Path, tmp_path: Path) -> None:
    result = cli(
        "record_video",
        "--algo",
        "dqn",
        "--env",
        PONG,
        "-f",
        str(pong_run),
        "-n",
        "60",
        "-o",
        str(tmp_path),
        "--seed",
        "3",
    )
    assert result.returncode == 0, result.stderr
    video = tmp_path / f"dqn-{PONG}-step-0-to-step-60.mp4"
    assert video.stat().st_size > 1000
    frames = iio.imread(video)
    assert frames.shape[1:] == (210, 160, 3) and frames.shape[0] >= 60
    assert frames.std() > 1  # not a blank picture


def test_pong_benchmark_tiny_run_and_report(pong_run: Path, tmp_path: Path) -> None:
    """``python -m benchmarks run pong`` on a tiny budget: the short benchmark, and the long-run report of this
    module's run (an evaluations file added); the section shows both, without this machine's paths."""
    import numpy as np

    from benchmarks.speed import pong_throughput as pong

    run_dir = pong_run / "dqn" / f"{PONG}_1"
    np.savez(run_dir / "evaluations.npz", timesteps=np.array([1000, 2000]), results=-21 * np.ones((2, 5)))
    png = tmp_path / "curve.png"
    results = pong.run(["--warmup-steps", "50", "--train-steps", "50", "--env-steps", "50",
                        "--report", str(run_dir), "--png", str(png), "--previous", str(tmp_path / "none.json")])
    assert results["throughput"]["train_steps_measured"] >= 50 and results["throughput"]["env_fps"] > 0
    assert [e["timestep"] for e in results["long_run"]["evals"]] == [1000, 2000] and png.stat().st_size > 1000
    assert results["command"] == ("python -m benchmarks run pong --warmup-steps 50 --train-steps 50 --env-steps 50 "
                                  "--report RUN_DIR")
    section = pong.markdown(results)
    assert "| 2,000 |" in section and "-21.0 +- 0.0" in section and str(tmp_path) not in section
    kept = pong.run(["--keep-throughput", "--previous", str(pong.RESULTS_DIR / pong.RESULTS_NAME)])
    saved = pong.load_results(pong.RESULTS_DIR / pong.RESULTS_NAME)  # nothing measured: the recorded figures
    assert kept == {k: saved[k] for k in ("command", "throughput", "long_run")}
