"""The Kuka safety zone's cost-only mode and the ``"path"`` zone across the arm's direct way to the block."""

from __future__ import annotations

import numpy as np
import pytest

from sbagents.envs.kuka import SAFETY_ZONES, RobustPickAndPlaceEnv
from sbagents.envs.kuka.scripted import PATH_DETOUR, ScriptedPusher, run_episode

READY = (0.0, 0.6, 0.0, -1.4, 0.0, 1.1)  # benchmarks/configs/kuka_constrained.yml
DOWN = np.array([0.0, 0.0, -1.0], dtype=np.float32)  # straight down from the ready pose: into the path zone


def path_env(**kwargs: object) -> RobustPickAndPlaceEnv:
    return RobustPickAndPlaceEnv(control="ee", reward_type="dense", initial_joints=READY, safety_zone="path",
                                 **kwargs)  # type: ignore[arg-type]


def test_defaults_keep_the_blocking_zone() -> None:
    env = RobustPickAndPlaceEnv()
    assert (env.zone_mode, env.zone_penalty) == ("block", -50.0)
    assert path_env(zone_mode="cost").zone_penalty == 0.0
    with pytest.raises(ValueError, match="zone_mode"):
        RobustPickAndPlaceEnv(zone_mode="soft")
    env.close()


def test_cost_mode_applies_the_step_and_reports_each_zone_step() -> None:
    cost_env, penalty_env = path_env(zone_mode="cost"), path_env(zone_mode="cost", zone_penalty=-50.0)
    block_env = path_env()
    for env in (cost_env, penalty_env, block_env):
        env.reset(seed=0)
    zone = SAFETY_ZONES["path"]
    assert not zone.contains(cost_env.robot.ee_position())
    costs = []
    for _ in range(6):
        _, reward, _, _, info = cost_env.step(DOWN)
        _, penalised, _, _, penalty_info = penalty_env.step(DOWN)
        _, blocked, _, _, block_info = block_env.step(DOWN)
        costs.append(info["cost"])
        if zone.contains(cost_env.robot.ee_position()):  # applied: the end effector stays in the zone
            assert info["cost"] == 1.0 and info["violation"] == "safety_zone"
        assert reward > -5.0  # no -50 in cost-only mode
        assert penalised == pytest.approx(reward - 50.0 * info["cost"]) and penalty_info["cost"] == info["cost"]
        if block_info["violation"]:  # block mode: undone, the book's -50
            assert blocked == -50.0 and block_info["cost"] == 1.0
        assert not zone.contains(block_env.robot.ee_position())
    assert sum(costs) >= 3 and costs[-1] == 1.0
    for env in (cost_env, penalty_env, block_env):
        env.close()


def test_direct_push_crosses_the_path_zone_and_the_detour_does_not() -> None:
    env = path_env(zone_mode="cost")
    direct = ScriptedPusher(env, approach_height=0.004)  # straight from the ready pose to behind the block
    detour = ScriptedPusher(env, via=PATH_DETOUR)
    seeds = range(20)
    direct_runs = [run_episode(env, direct, seed=seed) for seed in seeds]
    detour_runs = [run_episode(env, detour, seed=seed) for seed in seeds]
    assert all(r["cost"] > 0 for r in direct_runs)
    assert np.mean([r["is_success"] for r in direct_runs]) >= 0.9
    assert np.mean([r["cost"] == 0 for r in detour_runs]) >= 0.95
    assert np.mean([r["is_success"] and r["cost"] == 0 for r in detour_runs]) >= 0.9
    env.close()
