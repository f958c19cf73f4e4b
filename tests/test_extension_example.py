"""docs/extending.md's example extension (``--grad-clip``) works as the page says, with no sbagents file edited: the
flag reaches the model, is recorded in args.yml and summary.json, prints its line, and RLlib refuses it in one line."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
from cli_helpers import REPO, check_error, run_main, summary

from sbagents.extensions import registered_extensions, unregister_extension

EXAMPLES = REPO / "docs" / "examples"
EXAMPLE = EXAMPLES / "grad_clip_extension.py"
TINY = ["-params", "n_envs:2", "n_steps:64", "batch_size:64", "n_epochs:1"]


@pytest.fixture
def example_on_path(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """The example module importable as a user's package; unregistered again afterwards."""
    monkeypatch.syspath_prepend(str(EXAMPLES))
    yield
    unregister_extension("grad_clip")
    sys.modules.pop("grad_clip_extension", None)


def test_the_page_shows_the_module_the_test_runs() -> None:
    page = (REPO / "docs" / "extending.md").read_text()
    assert EXAMPLE.read_text() in page


def test_the_flag_reaches_the_model_and_the_run_files(example_on_path: None, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    code = run_main("train", "--gym-packages", "grad_clip_extension", "--algo", "ppo", "--env",
                    "sbagents/GridWorld-v0", "-n", "256", "--seed", "0", "-f", str(tmp_path), "--eval-freq", "0",
                    "--final-eval-episodes", "1", "--verbose", "0", "--grad-clip", "0.3", *TINY)
    assert code == 0
    run_dir = next((tmp_path / "ppo").iterdir())
    args = yaml.safe_load((run_dir / "sbagents_GridWorld-v0" / "args.yml").read_text())
    assert args["grad_clip"] == 0.3
    assert summary(run_dir)["grad_clip"] == {"max_grad_norm": 0.3}  # read back from the trained model
    assert "gradient norm capped at 0.3" in capsys.readouterr().out
    assert [e.name for e in registered_extensions()][-1] == "grad_clip"  # after the built-in ones


def test_the_flag_reaches_every_model_of_a_per_group_run(example_on_path: None, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    """A run of one model per group calls the extension's hooks once per group's model: each model has the cap,
    and summary.json keeps each group's item under by_group."""
    code = run_main("train", "--gym-packages", "grad_clip_extension", "--algo", "ppo", "--env", "mpe2.simple_tag_v3",
                    "-n", "256", "--seed", "0", "-f", str(tmp_path), "--eval-freq", "0", "--final-eval-episodes", "0",
                    "--verbose", "0", "--grad-clip", "0.3", "-params", "policies:per_group", "n_envs:1", "n_steps:32",
                    "batch_size:32", "n_epochs:1")
    assert code == 0, capsys.readouterr().err
    run_dir = next((tmp_path / "ppo").iterdir())
    by_group = summary(run_dir)["by_group"]
    assert set(by_group) == {"adversary", "agent"}
    assert all(items["grad_clip"] == {"max_grad_norm": 0.3} for items in by_group.values())


def test_backends_and_algorithms_it_cannot_serve_refuse_it_in_one_line(
        example_on_path: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = run_main("train", "--gym-packages", "grad_clip_extension", "--backend", "rllib", "--algo", "ppo",
                    "--env", "treasure_hunt_v0", "-f", str(tmp_path), "--grad-clip", "0.3")
    check_error(code, capsys.readouterr().err, "--grad-clip not supported with --backend rllib")
    code = run_main("train", "--gym-packages", "grad_clip_extension", "--algo", "sac", "--env",
                    "sbagents/SmartHome-v0", "-f", str(tmp_path), "--grad-clip", "0.3")
    check_error(code, capsys.readouterr().err, "--grad-clip trains a2c, ppo, ppo_lstm, ppo_mask, dqn, qrdqn, not sac")
    assert not (tmp_path / "sac").exists()


def test_without_the_package_the_flag_is_unknown(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = run_main("train", "--algo", "ppo", "-f", str(tmp_path), "--grad-clip", "0.3")
    check_error(code, capsys.readouterr().err, "--grad-clip")
