"""Every bad input through the real CLI: one clear line, exit code 2, no traceback, nothing written."""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_helpers import cli

CASES = [
    (["--env", "GridWrld-v0"], "unknown env id 'GridWrld-v0'; did you mean sbagents/GridWorld-v0"),
    (["--algo", "foo"], "unknown algo 'foo'; available: a2c, ppo"),
    (["--algo", "sac"],
     "sac cannot learn sbagents/GridWorld-v0 (observation Discrete, action Discrete); algos that can: a2c"),
    (["--algo", "qlearning", "--env", "Pendulum-v1"], "qlearning cannot learn Pendulum-v1"),
    (["-n", "0"], "-n/--n-timesteps must be a positive integer, got 0"),
    (["-n", "-5"], "-n/--n-timesteps must be a positive integer, got -5"),
    (["-params", "learning_rate"], "-params expects key:value pairs"),
    (["-params", "learning_rate:[1,"], "is not a YAML scalar, list or mapping"),
    (["-params", "learnin_rate:0.1"], "unknown hyperparameter(s) learnin_rate for dqn"),
    (["-params", "learning_rate:__import__('os').system('true')"], "learning_rate must be a number"),
    (["--env-kwargs", "sise:5"], "unknown env kwarg(s) sise for sbagents/GridWorld-v0; accepted: goal"),
    (["-i", "missing.zip"], "--trained-agent missing.zip does not exist"),
    (["--num-threads", "x"], "argument --num-threads: invalid int value"),
]


def check_error(result, expected: str) -> None:  # type: ignore[no-untyped-def]
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert expected in lines[0]
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize(("args", "expected"), CASES, ids=[" ".join(a) for a, _ in CASES])
def test_bad_train_input(tmp_path: Path, args: list[str], expected: str) -> None:
    result = cli("train", "--algo", "dqn", "-f", str(tmp_path / "logs"), *args, cwd=tmp_path)
    check_error(result, expected)
    assert not list((tmp_path / "logs").glob("*/*")), "a run dir was left behind"


def test_config_errors(tmp_path: Path) -> None:
    bad_yaml = tmp_path / "bad.yml"
    bad_yaml.write_text("default:\n  n_timesteps: 10\n  policy: [oops\n")
    check_error(cli("train", "--algo", "dqn", "-conf", str(bad_yaml), "-f", str(tmp_path)),
                f"malformed YAML in {bad_yaml} line 4")
    no_entry = tmp_path / "no_entry.yml"
    no_entry.write_text("CartPole-v1:\n  n_timesteps: 10\n")
    check_error(cli("train", "--algo", "dqn", "-conf", str(no_entry), "-f", str(tmp_path)),
                "has no entry for 'sbagents/GridWorld-v0' and no 'default' (entries: CartPole-v1)")
    check_error(cli("train", "--algo", "dqn", "-conf", str(tmp_path / "nope.yml"), "-f", str(tmp_path)),
                "does not exist")
    assert not (tmp_path / "dqn").exists()


def test_not_a_model_and_unwritable_folder(tmp_path: Path) -> None:
    not_model = tmp_path / "model.zip"
    not_model.write_text("not a zip")
    check_error(cli("train", "-i", str(not_model), "-f", str(tmp_path / "logs")), "is not an SB3 model file")
    blocker = tmp_path / "file"
    blocker.write_text("")
    check_error(cli("train", "-f", str(blocker / "logs")), f"log folder {blocker / 'logs'} is not writable")


def test_bad_evaluate_input(tmp_path: Path) -> None:
    check_error(cli("evaluate", "--algo", "dqn", "--env", "GridWorld-v0", "-f", str(tmp_path)),
                "no dqn run for sbagents/GridWorld-v0")
    check_error(cli("evaluate", "--algo", "dqn", "--env", "Nope-v0", "-f", str(tmp_path)), "unknown env id")
