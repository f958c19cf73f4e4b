"""The book's envs check their constructor arguments against clear bounds (:mod:`sbagents.envs.bounds`): a huge
``max_steps`` or grid size is a ValueError naming the accepted range, which the CLIs print as one line, before
numba or an allocation sees it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from cli_helpers import check_error, run_main

from sbagents.envs.bounds import MAX_EPISODE_STEPS, MAX_GRID_SIDE
from sbagents.envs.gridworld import GridWorldEnv
from sbagents.envs.hazard_gridworld import HazardGridWorldEnv
from sbagents.envs.smart_home import SmartHomeEnv
from sbagents.envs.treasure_hunt import CooperativeTreasureHunt

HUGE = 12345678901234567890123456


@pytest.mark.parametrize(("cls", "kwargs", "message"), [
    (GridWorldEnv, {"max_steps": HUGE}, "max_steps must be an integer in 1..1,000,000,000, got 1234567890"),
    (GridWorldEnv, {"max_steps": 10**100_000}, "got an integer of about 100,001 digits"),
    (GridWorldEnv, {"size": 100_000}, f"size must be an integer in 1..{MAX_GRID_SIDE}, got 100000"),
    (GridWorldEnv, {"size": (5, 100_000)}, "size must be an integer in 1..256, got 100000"),
    (GridWorldEnv, {"size": True}, "size must be a pair of integers"),
    (HazardGridWorldEnv, {"max_steps": -1}, "max_steps must be an integer in 1..1,000,000,000, got -1"),
    (HazardGridWorldEnv, {"hazard_penalty": "a"}, "hazard_penalty must be a finite number <= 0, got 'a'"),
    (CooperativeTreasureHunt, {"grid_size": 100_000}, "grid_size must be an integer in 2..256, got 100000"),
    (CooperativeTreasureHunt, {"max_cycles": HUGE}, "max_cycles must be an integer in 1..1,000,000,000"),
    (CooperativeTreasureHunt, {"n_agents": 10_000}, "n_agents must be an integer in 1..64, got 10000"),
    (CooperativeTreasureHunt, {"obstacles": 5}, "obstacles must be a list of (row, col) cells"),
    (SmartHomeEnv, {"max_steps": 1e30}, "max_steps must be an integer in 1..1,000,000,000, got 1e+30"),
    (SmartHomeEnv, {"max_steps": 20, "warmup_steps": 20}, "warmup_steps must be an integer in 0..19, got 20"),
    (SmartHomeEnv, {"noise_std": float("inf")}, "noise_std must be a finite number in [0, 1e+06], got inf"),
    (SmartHomeEnv, {"success_share": 2}, "success_share must be a finite number in [0, 1], got 2"),
    (SmartHomeEnv, {"temp_range": 5}, "temp_range must be a finite (low, high) with low <= high, got 5"),
    (SmartHomeEnv, {"preferred_temp": "warm"}, "preferred_temp must be a finite number, got 'warm'"),
])
def test_out_of_bounds_arguments_name_the_range(cls: type, kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError) as info:
        cls(**kwargs)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_the_bounds_themselves_are_accepted() -> None:
    env = GridWorldEnv(size=(1, MAX_GRID_SIDE), start=(0, 0), goal=(0, 1), obstacles=(), max_steps=MAX_EPISODE_STEPS)
    assert env.observation_space.n == MAX_GRID_SIDE and env.max_steps == MAX_EPISODE_STEPS
    assert CooperativeTreasureHunt(grid_size=MAX_GRID_SIDE, n_agents=64, obstacles=()).grid_size == MAX_GRID_SIDE
    assert SmartHomeEnv(max_steps=MAX_EPISODE_STEPS, warmup_steps=0, success_share=1).max_steps == MAX_EPISODE_STEPS


@pytest.mark.parametrize(("env", "kwargs", "expected"), [
    ("GridWorld-v0", f"max_steps:{HUGE}", "--env-kwargs max_steps: integer '12345678901234567890123456' is outside"),
    ("GridWorld-v0", "max_steps:9223372036854775807", "max_steps must be an integer in 1..1,000,000,000"),
    ("GridWorld-v0", "size:100000", "cannot create sbagents/GridWorld-v0 with env kwargs size=100000: size must be"),
    ("GridWorld-v0", "max_steps:" + "9" * 100_000, "--env-kwargs max_steps: value of 100,000 characters is too long"),
    ("treasure_hunt_v0", "grid_size:100000", "grid_size must be an integer in 2..256, got 100000"),
])
def test_train_refuses_extreme_env_kwargs_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], env: str,
                                                      kwargs: str, expected: str) -> None:
    code = run_main("train", "--algo", "ppo", "--env", env, "-n", "1000", "--env-kwargs", kwargs,
                    "-f", str(tmp_path / "logs"))
    check_error(code, capsys.readouterr().err, expected)
    assert not (tmp_path / "logs").exists(), "a run dir was left behind"
