"""``--save-replay-buffer`` and ``-i``: an off-policy run continues with the transitions it had collected."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import check_error, run_main, summary

SAC = ("--algo", "sac", "--env", "Pendulum-v1", "--seed", "0", "--eval-freq", "0", "--final-eval-episodes", "0",
       "--verbose", "0", "-params", "learning_starts:100", "buffer_size:5000", "policy_kwargs:{net_arch: [16]}")


def _buffer_size(run_dir: Path) -> int:
    with np.load(run_dir / "replay_buffer.npz", allow_pickle=False) as data:  # numbers only: nothing to unpickle
        settings = json.loads(str(data["__settings__"]))
    return (settings["buffer_size"] if settings["full"] else settings["pos"]) * settings["n_envs"]


def test_buffer_saved_and_continued(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    logs = tmp_path / "logs"
    assert run_main("train", *SAC, "-n", "400", "-f", str(logs), "--save-freq", "300", "--save-replay-buffer") == 0
    first = logs / "sac" / "Pendulum-v1_1"
    assert _buffer_size(first) == 400  # the final save replaced the checkpoint's 300
    assert sorted(p.name for p in first.glob("*replay_buffer*")) == ["replay_buffer.npz"]  # one file, no partial left
    assert summary(first)["replay_buffer"] == {"loaded_transitions": None, "saved": True}

    assert run_main("train", *SAC, "-n", "200", "-f", str(logs), "--save-replay-buffer",
                    "-i", str(first / "Pendulum-v1.zip")) == 0
    second = logs / "sac" / "Pendulum-v1_2"
    assert summary(second)["replay_buffer"] == {"loaded_transitions": 400, "saved": True}
    assert _buffer_size(second) == 600
    assert "continued with the 400 transitions" in capsys.readouterr().out


def test_continuing_without_a_saved_buffer_starts_empty(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    assert run_main("train", *SAC, "-n", "200", "-f", str(logs)) == 0
    first = logs / "sac" / "Pendulum-v1_1"
    assert not (first / "replay_buffer.npz").exists()
    assert run_main("train", *SAC, "-n", "200", "-f", str(logs), "-i", str(first / "Pendulum-v1.zip")) == 0
    assert "replay_buffer" not in summary(logs / "sac" / "Pendulum-v1_2")


def test_on_policy_runs_refuse_the_flag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    logs = tmp_path / "logs"
    code = run_main("train", "--algo", "ppo", "--env", "CartPole-v1", "-n", "64", "-f", str(logs),
                    "--save-replay-buffer")
    check_error(code, capsys.readouterr().err, "--save-replay-buffer keeps the buffer of one off-policy model")
    assert not logs.exists()
