"""``python -m sbagents.collect --from-log PATH``: a run's transparency log becomes a Minari dataset of its complete
episodes (raw observations, actions, rewards, done flags, success), which ``train --pretrain`` clones; logs that cannot
give whole episodes get one line (exit 2) and no dataset."""

from __future__ import annotations

import csv
import gzip
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from cli_helpers import check_error, run_main

import sbagents  # noqa: F401 (registers the env ids)
from sbagents.datasets.logs import episodes_from_log

minari = pytest.importorskip("minari", reason="needs Minari: pip install -e '.[test]' (or the data extra)")
QUIET = ("--verbose", "0", "--eval-freq", "-1", "--final-eval-episodes", "2", "--seed", "0")


def logged_run(tmp_path: Path, algo: str, env: str, steps: int, *extra: str) -> Path:
    logs = tmp_path / "logs"
    assert run_main("train", "--algo", algo, "--env", env, "-n", str(steps), "-f", str(logs), "--transparency-log",
                    *extra, *QUIET) == 0
    (log,) = logs.rglob("transparency.csv*")
    return log


def test_a_smart_home_log_becomes_the_episodes_it_played(datasets: Path, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """SmartHome (Box observations, normalized in training: the log and the dataset hold the raw ones) over 256
    steps of each of 2 envs: 4 complete episodes of 100 steps and 2 cut off by the end of training."""
    log = logged_run(tmp_path, "ppo", "SmartHome-v0", 512, "-params", "n_envs:2", "n_steps:128")
    assert run_main("collect", "--env", "SmartHome-v0", "--from-log", str(log), "--dataset",
                    "sbagents/home-log-v0", "--ref-episodes", "0") == 0
    assert "dataset sbagents/home-log-v0: 4 episodes in" in capsys.readouterr().out
    dataset = minari.load_dataset("sbagents/home-log-v0")
    assert dataset.total_episodes == 4 and dataset.total_steps == 400
    assert "2 episodes without their end left out" in dataset.storage.metadata["description"]
    env = gym.make("sbagents/SmartHome-v0")
    for episode in dataset.iterate_episodes():
        assert len(episode.actions) == 100 and episode.truncations[-1] and not episode.terminations.any()
        assert all(env.observation_space.contains(o) for o in episode.observations)
        assert np.array_equal(episode.observations[-1], episode.observations[-2])  # the unlogged last one repeated
        assert np.abs(episode.observations[:, 0]).max() > 5  # raw temperatures, not normalized values
    with log.open(newline="") as handle:
        first_return = sum(float(row["reward"]) for row in csv.DictReader(handle)
                           if row["env"] == "0" and row["episode"] == "0")
    assert dataset[0].rewards.sum() == pytest.approx(first_return, rel=1e-5)  # env 0's first episode ends first


def test_a_grid_log_trains_a_clone(datasets: Path, tmp_path: Path) -> None:
    """GridWorld's discrete observations and actions, from a compressed log, cloned by ``--pretrain``."""
    log = logged_run(tmp_path, "qlearning", "GridWorld-v0", 3000)
    packed = log.with_suffix(".csv.gz")
    packed.write_bytes(gzip.compress(log.read_bytes()))
    episodes, dropped = episodes_from_log(packed, gym.spaces.Discrete(25), gym.spaces.Discrete(4))
    assert episodes and dropped <= 1 and all(e.terminations[-1] or e.truncations[-1] for e in episodes)
    assert all(len(e.observations) == len(e.actions) + 1 for e in episodes)
    assert run_main("collect", "--env", "GridWorld-v0", "--from-log", str(packed), "--episodes", "5", "--dataset",
                    "sbagents/grid-log-v0", "--ref-episodes", "0") == 0
    assert minari.load_dataset("sbagents/grid-log-v0").total_episodes == 5
    assert run_main("train", "--algo", "dqn", "--env", "GridWorld-v0", "--pretrain", "sbagents/grid-log-v0",
                    "--pretrain-steps", "50", "-n", "64", "-f", str(tmp_path / "clone"), *QUIET) == 0


def test_logs_that_cannot_give_whole_episodes_are_one_line(datasets: Path, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    log = logged_run(tmp_path, "qlearning", "GridWorld-v0", 200)
    book = tmp_path / "book.csv"
    book.write_text("Episode,Step,Obs,Action,Reward\n0,0,1,2,-1\n")
    team = tmp_path / "team.csv"
    team.write_text("env,agent,episode,step,obs_0,action_0,reward,terminated,truncated\n0,a,0,0,1,1,0,False,False\n")
    skipped = tmp_path / "skipped.csv"
    lines = log.read_text().splitlines()
    skipped.write_text("\n".join([lines[0], *lines[1::2]]) + "\n")
    common = ("--dataset", "sbagents/bad-log-v0", "--ref-episodes", "0")
    capsys.readouterr()
    for env, path, expected in (
            ("GridWorld-v0", tmp_path / "none.csv", "no such file"),
            ("GridWorld-v0", book, "not a transparency log with done flags"),
            ("GridWorld-v0", team, "a team's log"),
            ("GridWorld-v0", skipped, "a log that skips steps (every > 1) cannot become a dataset"),
            ("SmartHome-v0", log, "the log has 2 observation and action columns; this env takes 5 + 2"),
    ):
        check_error(run_main("collect", "--env", env, "--from-log", str(path), *common), capsys.readouterr().err,
                    expected)
    check_error(run_main("collect", "--env", "GridWorld-v0", "--from-log", str(log), "--policy", "random", *common),
                capsys.readouterr().err, "give one of them")
    check_error(run_main("collect", "--env", "GridWorld-v0", "--policy", "random", *common),
                capsys.readouterr().err, "--episodes N")
    assert not (datasets / "sbagents" / "bad-log-v0").exists()
