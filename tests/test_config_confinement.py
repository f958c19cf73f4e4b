"""A finished run's ``config.yml`` never makes evaluate, export or record write outside the run dir: wrapper
arguments (``env_wrapper``, ``vec_env_wrapper``) and ``monitor_kwargs`` that name a file or folder are refused in one
line (exit 2), before any env is built, and the file they name is neither created nor truncated."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest
import yaml
from cli_helpers import check_error, last_json, run_main

from sbagents.api import EvalOptions, ExecOptions, OutputOptions, TrainSpec, train

ENV = "CartPole-v1"
RUN = ("--algo", "ppo", "--env", ENV)


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished PPO CartPole run: the log folder."""
    logs = tmp_path_factory.mktemp("confinement") / "logs"
    train(TrainSpec("ppo", ENV, 64, {"n_envs": 1, "n_steps": 64, "batch_size": 64,
                                     "policy_kwargs": {"net_arch": [8]}}),
          OutputOptions(logs), EvalOptions(eval_freq=0, final_eval_episodes=0), ExecOptions(seed=0, verbose=0))
    return logs


@pytest.fixture()
def logs(trained: Path, tmp_path: Path) -> Path:
    """A copy of the trained log folder to tamper with."""
    return Path(shutil.copytree(trained, tmp_path / "logs"))


def config_file(logs: Path) -> Path:
    return logs / "ppo" / f"{ENV}_1" / ENV / "config.yml"


def set_config(logs: Path, **items: Any) -> None:
    path = config_file(logs)
    entry = yaml.safe_load(path.read_text())
    entry.update(items)
    path.write_text(yaml.safe_dump(entry))


def elsewhere_cases(target: Path) -> list[dict[str, Any]]:
    return [
        {"env_wrapper": [{"gymnasium.wrappers.RecordVideo": {"video_folder": str(target)}}]},
        {"vec_env_wrapper": [{"stable_baselines3.common.vec_env.VecMonitor": {"filename": str(target / "m")}}]},
        {"env_wrapper": [{"gymnasium.wrappers.RecordVideo": {"video_folder": "videos",
                                                             "name_prefix": f"../../{target.name}/v"}}]},
        {"monitor_kwargs": {"filename": str(target / "m")}},
        {"env_wrapper": [{"gymnasium.wrappers.TimeLimit": {"max_episode_steps": 10, "extra": [str(target)]}}]},
    ]


@pytest.mark.parametrize("case", range(5))
def test_wrapper_paths_in_a_run_config_are_refused(case: int, logs: Path, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "elsewhere"
    target.mkdir()
    existing = target / "m.monitor.csv"
    existing.write_text("keep me\n")
    set_config(logs, **elsewhere_cases(target)[case])
    before = sorted(p.name for p in logs.rglob("*"))
    code = run_main("evaluate", *RUN, "-f", str(logs), "-n", "1")
    check_error(code, capsys.readouterr().err, "names a file or folder")
    assert sorted(p.name for p in target.iterdir()) == ["m.monitor.csv"]
    assert existing.read_text() == "keep me\n", "a file outside the run dir was truncated"
    assert sorted(p.name for p in logs.rglob("*")) == before


@pytest.mark.parametrize("command", [("export",), ("record_video", "-n", "5")])
def test_every_command_that_builds_the_env_refuses(command: tuple[str, ...], logs: Path, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "elsewhere"
    set_config(logs, env_wrapper=[{"gymnasium.wrappers.RecordVideo": {"video_folder": str(target)}}])
    code = run_main(command[0], *RUN, "-f", str(logs), *command[1:])
    check_error(code, capsys.readouterr().err, "names a file or folder")
    assert not target.exists()


def test_wrapper_arguments_that_are_no_paths_still_evaluate(logs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    set_config(logs, env_wrapper=[{"gymnasium.wrappers.ClipReward": {"min_reward": -1, "max_reward": 0.5}}],
               monitor_kwargs={"info_keywords": []})
    assert run_main("evaluate", *RUN, "-f", str(logs), "-n", "2", "--json") == 0
    result = last_json(capsys.readouterr().out)
    assert result["n_episodes"] == 2 and result["mean_return"] > 0


def test_a_wrapper_rejecting_its_config_arguments_is_one_line(logs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    set_config(logs, env_wrapper=[{"gymnasium.wrappers.TimeLimit": {"no_such_argument": 1}}])
    code = run_main("evaluate", *RUN, "-f", str(logs), "-n", "1")
    check_error(code, capsys.readouterr().err, "env_wrapper gymnasium.wrappers.common.TimeLimit cannot be built")


@pytest.mark.parametrize("text", ["", "# nothing\n", "{}\n", "null\n"])
def test_an_empty_run_config_is_refused(text: str, logs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Training always writes the run's hyperparameters, so an empty ``config.yml`` is a damaged run: refused rather
    than evaluated without the settings it was trained with."""
    config_file(logs).write_text(text)
    code = run_main("evaluate", *RUN, "-f", str(logs), "-n", "1")
    check_error(code, capsys.readouterr().err, "holds no settings")
