"""Tests of the Kuka push environments (sbagents.envs.kuka) and the scripted controller."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch

from sbagents.envs.kuka import (
    KukaPushEnv,
    PickAndPlaceEnv,
    PickAndPlaceGoalEnv,
    RobustPickAndPlaceEnv,
    SafetyZone,
)
from sbagents.envs.kuka.scripted import ScriptedPusher, run_episode
from sbagents.envs.kuka.tasks import SAFETY_ZONES

torch.set_num_threads(1)

ENTRY_POINTS = {
    "sbagents/PickAndPlace-v0": "sbagents.envs.kuka:PickAndPlaceEnv",
    "sbagents/RobustPickAndPlace-v0": "sbagents.envs.kuka:RobustPickAndPlaceEnv",
    "sbagents/PickAndPlaceGoal-v0": "sbagents.envs.kuka:PickAndPlaceGoalEnv",
}
for _id, _entry in ENTRY_POINTS.items():
    if _id not in gym.registry:
        gym.register(id=_id, entry_point=_entry)


def rollout(env: gym.Env, seed: int, n: int = 30, other: gym.Env | None = None) -> list[np.ndarray]:
    """Observations of ``n`` seeded random steps (resetting on episode end).

    If ``other`` is given, it is stepped with unrelated random actions between the steps of ``env``.
    """
    rng, other_rng = np.random.default_rng(1), np.random.default_rng(9)
    obs, _ = env.reset(seed=seed)
    out = [np.asarray(obs if not isinstance(obs, dict) else obs["observation"]).copy()]
    for _ in range(n):
        if other is not None:
            other.step(other_rng.uniform(-0.1, 0.1, 6).astype(np.float32))
        low, high = env.action_space.low, env.action_space.high  # type: ignore[attr-defined]
        obs, _, term, trunc, _ = env.step(rng.uniform(low, high).astype(np.float32))
        out.append(np.asarray(obs if not isinstance(obs, dict) else obs["observation"]).copy())
        if term or trunc:
            obs, _ = env.reset()
    return out


def test_book_spaces_and_names() -> None:
    env = PickAndPlaceEnv()
    assert env.observation_space.shape == (12,)
    assert env.action_space.shape == (6,)
    assert np.allclose(env.action_space.low, -0.1) and np.allclose(env.action_space.high, 0.1)
    assert len(env.obs_names) == 12 and len(env.action_names) == 6
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    np.testing.assert_allclose(obs[:6], 0.0, atol=1e-6)  # joints reset to 0
    np.testing.assert_allclose(obs[6:9], [0.5, 0.0, 0.009], atol=1e-3)  # block at rest
    np.testing.assert_allclose(obs[9:], [0.5, 0.5, 0.009], atol=1e-6)  # target at resting height
    for key in ("is_success", "cost", "violation", "object_scale", "object_mass"):
        assert key in info
    for _ in range(20):
        obs, reward, term, trunc, info = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs)
        assert reward == -1.0 and not term and not trunc and info["cost"] == 0.0
    ee_env = PickAndPlaceEnv(control="ee")
    assert ee_env.action_space.shape == (3,) and len(ee_env.action_names) == 3
    env.close()
    ee_env.close()


def test_joint_targets_clipped_and_arm_moves() -> None:
    env = PickAndPlaceEnv()
    env.reset(seed=0)
    for _ in range(40):
        obs, *_ = env.step(np.full(6, 0.1, dtype=np.float32))
    # the arm follows the commands (enough substeps) and stays within the joint limits
    assert obs[0] > 2.0 and np.all(np.abs(obs[:6]) <= np.pi)
    assert np.all(env.robot.joint_targets <= env.robot.upper + 1e-9)
    env.close()


def test_episode_truncates_after_100_steps() -> None:
    env = PickAndPlaceEnv()
    env.reset(seed=0)
    for t in range(100):
        _, _, term, trunc, info = env.step(np.zeros(6, dtype=np.float32))
        assert not term
        assert trunc == (t == 99)
    assert info["is_success"] is False
    env.close()


def test_success_and_drop_rules() -> None:
    env = PickAndPlaceEnv()
    env.reset(seed=0)
    env.sim.set_base_pose(env.task.block, [0.5, 0.47, 0.009])  # within 0.05 of the target
    _, reward, term, trunc, info = env.step(np.zeros(6, dtype=np.float32))
    assert (reward, term, trunc, info["is_success"]) == (100.0, True, False, True)
    env.reset(seed=0)
    env.sim.set_base_pose(env.task.block, [1.2, 0.0, 0.009])  # out of the arm's reach
    _, reward, term, _, info = env.step(np.zeros(6, dtype=np.float32))
    assert (reward, term, info["is_success"]) == (-10.0, True, False)
    dense = PickAndPlaceEnv(reward_type="dense")
    dense.reset(seed=0)
    _, reward, *_ = dense.step(np.zeros(6, dtype=np.float32))
    ee = dense.robot.ee_position()
    expected = -(np.linalg.norm(ee - [0.5, 0.0, 0.009]) + 0.5)
    assert reward == pytest.approx(expected, abs=0.01)
    env.close()
    dense.close()


def test_robust_randomisation_and_noise() -> None:
    env = RobustPickAndPlaceEnv()
    scales, masses = [], []
    for seed in range(8):
        obs, info = env.reset(seed=seed)
        scales.append(info["object_scale"])
        masses.append(info["object_mass"])
        assert info["object_mass"] == pytest.approx(env.sim.client.getDynamicsInfo(env.task.block, -1)[0])
    assert all(0.5 <= s <= 1.5 for s in scales) and len(set(scales)) == 8
    assert all(0.1 <= m <= 1.0 for m in masses)
    noisy = np.array([env._get_obs()[6:9] - env.task.object_position() for _ in range(400)])
    assert 0.04 < noisy.std() < 0.06 and np.abs(noisy.mean()) < 0.01
    env.close()


def test_safety_zone_step_is_undone() -> None:
    zone = SafetyZone((0.4, -0.3, 0.0), (0.9, 0.3, 1.5))
    env = RobustPickAndPlaceEnv(control="ee", safety_zone=zone, noise_level=0.0)
    env.reset(seed=0)
    before = env.robot.ee_position()
    hits = 0
    for _ in range(30):  # drive the end effector towards +x, into the zone
        _, reward, _, _, info = env.step(np.array([1.0, 0.0, -0.3], dtype=np.float32))
        assert not zone.contains(env.robot.ee_position())
        if info["violation"] == "safety_zone":
            hits += 1
            assert reward == -50.0 and info["cost"] == 1.0
        else:
            assert info["cost"] == 0.0
    assert hits > 0 and env.robot.ee_position()[0] > before[0]
    # the book's zone contains the target; the default one does not
    target = np.array([0.5, 0.5, 0.009])
    assert SAFETY_ZONES["book"].contains(target) and not SAFETY_ZONES["default"].contains(target)
    env.close()


@pytest.mark.parametrize("env_id", list(ENTRY_POINTS))
def test_checkers(env_id: str) -> None:
    from gymnasium.utils.env_checker import check_env as gym_check
    from stable_baselines3.common.env_checker import check_env as sb3_check

    env = gym.make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gym_check(env.unwrapped, skip_render_check=True)
        sb3_check(env.unwrapped)
    base = env.unwrapped
    assert isinstance(base, KukaPushEnv)
    assert isinstance(base.obs_names, tuple) and isinstance(base.action_names, tuple)
    env.close()


def test_seeding_and_two_envs_in_one_process() -> None:
    a, b = RobustPickAndPlaceEnv(), RobustPickAndPlaceEnv()
    alone = np.array(rollout(a, seed=5))
    np.testing.assert_array_equal(alone, np.array(rollout(a, seed=5)))  # same seed, same trajectory
    b.reset(seed=123)
    a2 = RobustPickAndPlaceEnv()
    together = np.array(rollout(a2, seed=5, other=b))  # a neighbour steps in between
    np.testing.assert_array_equal(alone, together)
    assert not np.array_equal(alone, np.array(rollout(b, seed=6)))
    for env in (a, b, a2):
        env.close()


def test_subproc_vec_env_independent() -> None:
    from stable_baselines3.common.vec_env import SubprocVecEnv

    vec = SubprocVecEnv([lambda: RobustPickAndPlaceEnv() for _ in range(4)], start_method="fork")
    vec.env_method("reset", seed=11, indices=[0, 2])
    vec.env_method("reset", seed=99, indices=[1, 3])
    actions = np.random.default_rng(0).uniform(-0.1, 0.1, (20, 6)).astype(np.float32)
    trajectories: list[list[np.ndarray]] = [[] for _ in range(4)]
    for t in range(20):
        acts = np.stack([actions[t], -actions[t], actions[t], actions[t] * 0.5])
        vec.step_async(acts)
        obs = np.asarray(vec.step_wait()[0])
        for i in range(4):
            trajectories[i].append(obs[i])
    vec.close()
    np.testing.assert_array_equal(np.array(trajectories[0]), np.array(trajectories[2]))
    assert not np.array_equal(np.array(trajectories[0]), np.array(trajectories[1]))


def test_rgb_array_frame() -> None:
    env = PickAndPlaceEnv(render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert isinstance(frame, np.ndarray) and frame.dtype == np.uint8
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.shape[0] > 0
    assert frame.std() > 5  # not a blank image
    env.close()


def test_goal_env_compute_reward_vectorised() -> None:
    env = PickAndPlaceGoalEnv()
    obs, _ = env.reset(seed=0)
    assert set(obs) == {"observation", "achieved_goal", "desired_goal"}
    targets = {tuple(env.reset(seed=s)[0]["desired_goal"]) for s in range(5)}
    assert len(targets) == 5  # random target per episode
    achieved = np.zeros((4, 3))
    desired = np.array([[0.0, 0.0, 0.0], [0.04, 0.0, 0.0], [0.06, 0.0, 0.0], [1.0, 1.0, 0.0]])
    rewards = env.compute_reward(achieved, desired, [{}] * 4)
    np.testing.assert_array_equal(rewards, [0.0, 0.0, -1.0, -1.0])
    obs, reward, term, _, info = env.step(env.action_space.sample())
    assert reward == env.compute_reward(obs["achieved_goal"], obs["desired_goal"], info)
    assert not term
    env.close()


def test_her_sac_runs() -> None:
    from stable_baselines3 import SAC, HerReplayBuffer

    env = PickAndPlaceGoalEnv(max_steps=20)
    model = SAC(
        "MultiInputPolicy",
        env,
        replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs={"n_sampled_goal": 4, "goal_selection_strategy": "future"},
        learning_starts=40,
        batch_size=32,
        policy_kwargs={"net_arch": [64, 64]},
        seed=0,
        device="cpu",
    )
    model.learn(80)  # plumbing: 4 episodes, 40 gradient steps on HER samples
    assert model.replay_buffer is not None and model.replay_buffer.size() > 0
    assert model.num_timesteps == 80
    env.close()


@pytest.mark.parametrize("cls", [PickAndPlaceEnv, RobustPickAndPlaceEnv])
def test_scripted_controller_succeeds(cls: type) -> None:
    env = cls()
    controller = ScriptedPusher(env)
    results = [run_episode(env, controller, seed=seed) for seed in range(20)]
    success = np.mean([r["is_success"] for r in results])
    assert success >= 0.9, success
    assert sum(r["cost"] for r in results) == 0.0
    env.close()
