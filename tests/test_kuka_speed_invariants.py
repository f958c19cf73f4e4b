"""Speed work on the Kuka envs must not change the push envs' trajectories (issue 20, part 5).

The numbers below were recorded with the code before the speed changes (PyBullet 3.2.7, DIRECT
client): a scripted ee-control push of ``sbagents/PickAndPlace-v0`` and random ee actions from the book's
singular all-zero pose (where inverse kinematics retries from the ready pose). The tolerance allows
for float32 rounding only; the physics is deterministic for a given seed and action sequence.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from sbagents.envs.kuka import KukaPickAndPlaceEnv, PickAndPlaceEnv, PickAndPlaceGoalEnv
from sbagents.envs.kuka.robot import READY_POSE
from sbagents.envs.kuka.scripted import ScriptedPusher

#: Observations (12,) after steps 8, 16, 24 and 32 of the scripted push below (seed 3).
SCRIPTED_OBS = [
    [-0.203344, 0.8386182, 0.0732814, -1.796532, -0.1144015, 0.5088482, 0.4999994, -3.889593e-06, 0.00898847]
    + [0.5, 0.5, 0.009],
    [0.02123511, 0.9667497, 0.03003756, -1.776574, -0.06348851, 0.3993716, 0.4999259, 0.04811144, 0.009139067]
    + [0.5, 0.5, 0.009],
    [0.437789, 1.001935, -0.1322407, -1.684364, 0.2461843, 0.4719571, 0.5007908, 0.2014279, 0.008675633]
    + [0.5, 0.5, 0.009],
    [0.8235074, 1.119367, -0.3697661, -1.455696, 0.5498844, 0.6708758, 0.5006066, 0.353562, 0.008462777]
    + [0.5, 0.5, 0.009],
]
#: Observation (12,) after 25 random ee actions from the all-zero pose (seed 1, ``default_rng(0)`` actions).
RANDOM_OBS = [0.182948, 0.7364182, -0.05118892, -0.2741241, 0.0405841, 2.092962, 0.4999981, -8.417825e-06]
RANDOM_OBS += [0.008988468, 0.5, 0.5, 0.009]


def test_scripted_ee_push_trajectory_is_pinned() -> None:
    env = PickAndPlaceEnv(control="ee", initial_joints=READY_POSE[:6])
    controller = ScriptedPusher(env)
    obs, _ = env.reset(seed=3)
    controller.reset()
    seen, total, steps = [], 0.0, 0
    terminated = truncated = False
    info: dict = {}
    while not (terminated or truncated):
        obs, reward, terminated, truncated, info = env.step(controller.act(obs))
        total += reward
        steps += 1
        if steps % 8 == 0:
            seen.append(obs)
    env.close()
    assert (steps, total, terminated, info["is_success"]) == (38, 63.0, True, True)
    np.testing.assert_allclose(np.array(seen), np.array(SCRIPTED_OBS, dtype=np.float32), rtol=0, atol=2e-6)


def test_random_ee_trajectory_from_singular_pose_is_pinned() -> None:
    env = PickAndPlaceEnv(control="ee")
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=1)
    for _ in range(25):
        obs, *_ = env.step(rng.uniform(-1, 1, 3))
    env.close()
    np.testing.assert_allclose(obs, np.array(RANDOM_OBS, dtype=np.float32), rtol=0, atol=2e-6)


@pytest.mark.parametrize("make", [PickAndPlaceGoalEnv, KukaPickAndPlaceEnv])
def test_kinematics_leave_the_arm_state_unchanged(make: Callable[[], Any]) -> None:
    env = make()
    env.reset(seed=0)
    env.step(env.action_space.sample())
    robot = env.robot
    angles, velocities = robot.joint_state()
    assert np.abs(velocities).max() > 0  # mid-motion: a restore that zeroed them would show
    ee = robot.ee_position()
    target = ee + np.array([0.03, -0.02, -0.04])
    q = robot.inverse_kinematics(target)
    cached = robot.forward_kinematics(q)  # the solution's own end effector, remembered by inverse_kinematics
    robot._last_solution = None
    np.testing.assert_array_equal(cached, robot.forward_kinematics(q))
    assert np.linalg.norm(cached - target) < 0.01
    after_angles, after_velocities = robot.joint_state()
    np.testing.assert_array_equal(after_angles, angles)
    np.testing.assert_array_equal(after_velocities, velocities)
    np.testing.assert_array_equal(robot.ee_position(), ee)
    env.close()
