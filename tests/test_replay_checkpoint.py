"""``train -i <checkpoint>`` continues with that checkpoint's replay buffer or, where the run dir holds only a buffer
of another step (``replay_buffer.npz`` is replaced at each checkpoint and at the end), says so in one warning line and
starts with an empty buffer: it never continues a model with transitions it was not saved with."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run_main, summary

from sbagents.state_files import replay_buffer_steps

DQN = ("--algo", "dqn", "--env", "CartPole-v1", "--seed", "0", "--eval-freq", "0", "--final-eval-episodes", "0",
       "--verbose", "0", "-params", "learning_starts:50", "buffer_size:5000", "policy_kwargs:{net_arch: [8]}")


@pytest.fixture(scope="module")
def first(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A DQN run of 400 steps with checkpoints at 200 and 400 and its buffer kept: the run dir."""
    logs = tmp_path_factory.mktemp("replay") / "logs"
    assert run_main("train", *DQN, "-n", "400", "-f", str(logs), "--save-freq", "200", "--save-replay-buffer") == 0
    return logs / "dqn" / "CartPole-v1_1"


def _continue(run_dir: Path, model: str, tmp_path: Path, *extra: str) -> Path:
    logs = tmp_path / "logs"
    assert run_main("train", *DQN, "-n", "100", "-f", str(logs), "-i", str(run_dir / model), *extra) == 0
    return logs / "dqn" / "CartPole-v1_1"


def _warnings(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("warning: ")]


def test_the_buffer_records_its_step(first: Path) -> None:
    assert replay_buffer_steps(first / "replay_buffer.npz") == 400
    assert sorted(p.name for p in first.glob("rl_model_*_steps.zip")) == ["rl_model_200_steps.zip",
                                                                         "rl_model_400_steps.zip"]


@pytest.mark.parametrize("model", ["CartPole-v1.zip", "rl_model_400_steps.zip"])
def test_a_model_of_the_buffer_step_continues_with_it(model: str, first: Path, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    second = _continue(first, model, tmp_path)
    assert summary(second)["replay_buffer"] == {"loaded_transitions": 400, "saved": False}
    assert _warnings(capsys.readouterr().err) == []


def test_an_earlier_checkpoint_starts_empty_and_says_so(first: Path, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    second = _continue(first, "rl_model_200_steps.zip", tmp_path, "--save-replay-buffer")
    warnings = _warnings(capsys.readouterr().err)
    assert len(warnings) == 1, warnings
    assert "saved at step 400, this model at step 200" in warnings[0]
    assert "continuing with an empty replay buffer" in warnings[0]
    item = summary(second)["replay_buffer"]
    assert item["loaded_transitions"] is None and "step 400" in item["not_loaded"]
    with np.load(second / "replay_buffer.npz", allow_pickle=False) as data:
        settings = json.loads(str(data["__settings__"]))
    assert settings["pos"] == 100 and not settings["full"]  # only this run's own 100 transitions
    assert settings["num_timesteps"] == 300


def test_a_checkpoint_of_a_run_without_a_buffer_says_so(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    logs = tmp_path / "plain"
    assert run_main("train", *DQN, "-n", "200", "-f", str(logs), "--save-freq", "100") == 0
    second = _continue(logs / "dqn" / "CartPole-v1_1", "rl_model_100_steps.zip", tmp_path)
    warnings = _warnings(capsys.readouterr().err)
    assert len(warnings) == 1 and "rl_model_100_steps.zip has no replay buffer saved with it" in warnings[0]
    assert summary(second)["replay_buffer"]["loaded_transitions"] is None


def test_a_buffer_that_records_no_step_is_not_a_checkpoint_s(first: Path, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """A buffer saved before the step was recorded: still the final model's (as before), never a checkpoint's."""
    old = Path(shutil.copytree(first, tmp_path / "old"))
    with np.load(old / "replay_buffer.npz", allow_pickle=False) as data:
        arrays = {name: data[name] for name in data.files}
    settings = json.loads(str(arrays["__settings__"]))
    del settings["num_timesteps"]
    arrays["__settings__"] = np.asarray(json.dumps(settings))
    np.savez(old / "replay_buffer.npz", **arrays)
    assert replay_buffer_steps(old / "replay_buffer.npz") is None
    second = _continue(old, "rl_model_400_steps.zip", tmp_path / "a")
    warnings = _warnings(capsys.readouterr().err)
    assert len(warnings) == 1 and "does not record the step it was saved at" in warnings[0]
    assert summary(second)["replay_buffer"]["loaded_transitions"] is None
    third = _continue(old, "CartPole-v1.zip", tmp_path / "b")
    assert summary(third)["replay_buffer"]["loaded_transitions"] == 400
