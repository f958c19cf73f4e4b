"""Tests of the Kuka pick and place with a gripper (sbagents.envs.kuka.pick) and its scripted controller."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch

from sbagents.envs.kuka import KukaPickAndPlaceEnv, RobustKukaPickAndPlaceEnv
from sbagents.envs.kuka.gripper import MAX_WIDTH
from sbagents.envs.kuka.pick_task import BLOCK_SIZE
from sbagents.envs.kuka.scripted_pick import ScriptedPicker, run_episode

torch.set_num_threads(1)

ENTRY_POINTS = {
    "sbagents/KukaPickAndPlace-v0": "sbagents.envs.kuka:KukaPickAndPlaceEnv",
    "sbagents/RobustKukaPickAndPlace-v0": "sbagents.envs.kuka:RobustKukaPickAndPlaceEnv",
}
for _id, _entry in ENTRY_POINTS.items():
    if _id not in gym.registry:
        gym.register(id=_id, entry_point=_entry)

#: Layout of ``obs["observation"]``.
EE, FINGER, OBJECT = slice(0, 3), 6, slice(7, 10)


def rollout(env: KukaPickAndPlaceEnv, seed: int, n: int = 30) -> np.ndarray:
    """Concatenated observations of a reset with ``seed`` and ``n`` seeded random steps."""
    rng = np.random.default_rng(1)
    obs, _ = env.reset(seed=seed)
    out = []
    for _ in range(n):
        out.append(np.concatenate([obs[k] for k in ("observation", "achieved_goal", "desired_goal")]))
        obs, *_ = env.step(rng.uniform(-1, 1, 4).astype(np.float32))
    return np.array(out)


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
    assert isinstance(base, KukaPickAndPlaceEnv)
    assert len(base.obs_names) == base.observation_space["observation"].shape[0] == 19  # type: ignore[index]
    assert base.action_names == ("d_ee_x", "d_ee_y", "d_ee_z", "d_finger_width")
    env.close()


def test_seeding_determinism() -> None:
    a, b = KukaPickAndPlaceEnv(), RobustKukaPickAndPlaceEnv()
    first = rollout(a, seed=3)
    b.reset(seed=11)
    b.step(b.action_space.sample())  # a neighbour in the same process must not disturb ``a``
    np.testing.assert_array_equal(first, rollout(a, seed=3))
    assert not np.array_equal(first, rollout(a, seed=4))
    robust = rollout(b, seed=5)
    np.testing.assert_array_equal(robust, rollout(b, seed=5))  # noise, scale and mass come from np_random too
    a.close()
    b.close()


def test_reset_distribution() -> None:
    env = KukaPickAndPlaceEnv()
    starts, targets = [], []
    for seed in range(300):
        obs, info = env.reset(seed=seed)
        starts.append(obs["achieved_goal"])
        targets.append(obs["desired_goal"])
        assert not info["is_success"] or info["distance"] < 0.05
    starts_a, targets_a = np.array(starts), np.array(targets)
    half = BLOCK_SIZE / 2
    for points in (starts_a, targets_a):  # a 0.3 m square around (0.6, 0)
        assert np.all(np.abs(points[:, 0] - 0.6) <= 0.15 + 1e-3) and np.all(np.abs(points[:, 1]) <= 0.15 + 1e-3)
        assert np.ptp(points[:, 0]) > 0.25 and np.ptp(points[:, 1]) > 0.25
    np.testing.assert_allclose(starts_a[:, 2], half, atol=1e-3)  # the cube rests on the table
    heights = targets_a[:, 2] - half
    assert np.all(heights >= -1e-6) and np.all(heights <= 0.2 + 1e-6)
    on_table = np.mean(heights < 1e-6)
    assert 0.2 < on_table < 0.45  # panda-gym: on the table with probability 0.3 (plus U(0, 0.2) near 0: never)
    env.close()


def test_compute_reward_matches_step_and_is_vectorised() -> None:
    for reward_type in ("sparse", "dense"):
        env = KukaPickAndPlaceEnv(reward_type=reward_type)
        obs, _ = env.reset(seed=0)
        for _ in range(5):
            obs, reward, _, _, info = env.step(env.action_space.sample())
            expected = env.compute_reward(obs["achieved_goal"], obs["desired_goal"], info)
            assert reward == pytest.approx(float(expected))
        achieved = np.zeros((4, 3))
        desired = np.array([[0.0, 0.0, 0.0], [0.04, 0.0, 0.0], [0.06, 0.0, 0.0], [0.0, 0.3, 0.4]])
        batch = env.compute_reward(achieved, desired, [{}] * 4)
        assert batch.shape == (4,) and batch.dtype == np.float32
        if reward_type == "sparse":
            np.testing.assert_array_equal(batch, [0.0, 0.0, -1.0, -1.0])
        else:
            np.testing.assert_allclose(batch, [0.0, -0.04, -0.06, -0.5], atol=1e-6)
        assert env.compute_reward(achieved[None], desired[None], None).shape == (1, 4)
        env.close()


def test_truncated_at_50_never_terminated() -> None:
    env = KukaPickAndPlaceEnv()
    env.reset(seed=0)
    for t in range(1, 51):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        assert not terminated
        assert truncated == (t == 50)
    env.close()


def test_gripper_closes_and_opens() -> None:
    env = KukaPickAndPlaceEnv()
    obs, _ = env.reset(seed=0)
    assert obs["observation"][FINGER] == pytest.approx(MAX_WIDTH, abs=2e-3)
    widths = []
    for finger in (-1.0, -1.0, -1.0, 1.0, 1.0, 1.0):
        obs, *_ = env.step(np.array([0.0, 0.0, 0.0, finger], dtype=np.float32))
        widths.append(float(obs["observation"][FINGER]))
    assert widths[2] < 0.01  # closed on nothing
    assert widths[5] > MAX_WIDTH - 0.01  # open again
    assert widths[0] < MAX_WIDTH - 0.02 and widths[3] > widths[2] + 0.02
    env.close()


def test_scripted_picker_succeeds() -> None:
    env = gym.make("sbagents/KukaPickAndPlace-v0")
    controller = ScriptedPicker(env)
    results = [run_episode(env, controller, seed=seed) for seed in range(20)]
    assert np.mean([r["is_success"] for r in results]) >= 0.9
    assert all(r["length"] == 50 for r in results)
    assert sum(r["cost"] for r in results) == 0.0
    env.close()


def test_grip_holds_the_largest_heaviest_cube() -> None:
    env = KukaPickAndPlaceEnv(scale_range=(1.5, 1.5), mass_range=(1.0, 1.0), table_probability=0.0)
    controller = ScriptedPicker(env)
    results = [run_episode(env, controller, seed=seed) for seed in range(5)]
    assert env.task.scale == 1.5 and env.task.mass == 1.0
    assert sum(r["is_success"] for r in results) >= 4  # targets in the air: the 6 cm, 1 kg cube was carried
    env.close()


def test_robust_variant_info_and_perturbations() -> None:
    env = gym.make("sbagents/RobustKukaPickAndPlace-v0")
    base = env.unwrapped
    assert isinstance(base, RobustKukaPickAndPlaceEnv)
    assert base.attribute_ranges == {"object_scale": (0.5, 1.5), "object_mass": (0.1, 1.0)}
    scales, masses = set(), set()
    for seed in range(4):
        obs, info = env.reset(seed=seed)
        for key in ("is_success", "cost", "violation", "object_scale", "object_mass", "distance"):
            assert key in info
        assert 0.5 <= info["object_scale"] <= 1.5 and 0.1 <= info["object_mass"] <= 1.0
        scales.add(info["object_scale"])
        masses.add(info["object_mass"])
        # observed cube position is noisy, achieved_goal is the true one
        assert not np.allclose(obs["observation"][OBJECT], obs["achieved_goal"], atol=1e-4)
    assert len(scales) == 4 and len(masses) == 4
    controller = ScriptedPicker(env)
    results = [run_episode(env, controller, seed=seed) for seed in range(3)]
    assert sum(r["cost"] for r in results) == 0.0  # the default zone is away from the workspace
    env.close()


@pytest.mark.parametrize("zone_mode", ["block", "cost"])
def test_safety_zone(zone_mode: str) -> None:
    zone = ((0.5, -0.1, 0.2), (0.7, 0.1, 0.33))  # just below the ready pose's TCP (0.61, 0, 0.35)
    env = KukaPickAndPlaceEnv(safety_zone=zone, zone_mode=zone_mode)
    obs, _ = env.reset(seed=0)
    before = obs["observation"][EE].copy()
    obs, reward, _, _, info = env.step(np.array([0.0, 0.0, -1.0, 0.0], dtype=np.float32))
    assert info["violation"] == "safety_zone" and info["cost"] == 1.0
    assert reward == float(env.compute_reward(obs["achieved_goal"], obs["desired_goal"], info))
    moved = float(np.linalg.norm(obs["observation"][EE] - before))
    assert moved < 1e-3 if zone_mode == "block" else moved > 0.02
    obs, _, _, _, info = env.step(np.array([0.0, 0.0, 1.0, 0.0], dtype=np.float32))
    assert info["violation"] is None or zone_mode == "cost"
    env.close()


def test_rgb_array_frame() -> None:
    env = KukaPickAndPlaceEnv(render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert isinstance(frame, np.ndarray) and frame.dtype == np.uint8 and frame.shape == (240, 320, 3)
    assert frame.std() > 5
    env.close()


def test_her_sac_smoke() -> None:
    from stable_baselines3 import SAC, HerReplayBuffer

    env = KukaPickAndPlaceEnv(max_steps=20)
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
    assert model.replay_buffer is not None and model.replay_buffer.size() == 80
    assert model.num_timesteps == 80
    env.close()


def test_start_in_hand_holds_the_cube_while_the_jaw_closes() -> None:
    for make in (KukaPickAndPlaceEnv, RobustKukaPickAndPlaceEnv):
        env = make(start_in_hand=1.0)
        for seed in range(3):
            obs, _ = env.reset(seed=seed)
            start = obs["achieved_goal"].copy()
            assert obs["observation"][FINGER] < 2 * env.task.half_size + 0.002  # closed on the cube
            assert np.linalg.norm(obs["achieved_goal"][:2] - obs["observation"][EE][:2]) < 0.01  # between the fingers
            for _ in range(10):
                obs, *_ = env.step(np.array([0.0, 0.0, 0.0, -1.0], dtype=np.float32))
            assert abs(float(obs["achieved_goal"][2] - start[2])) < 0.01  # still held at its height
            env.reset(seed=seed)
            for _ in range(15):
                obs, *_ = env.step(np.array([0.0, 0.0, 0.0, 1.0], dtype=np.float32))
            assert obs["achieved_goal"][2] < env.task.half_size + 0.005  # let go: on the table
        env.close()


def test_start_in_hand_off_keeps_the_task_and_is_checked() -> None:
    plain, off = KukaPickAndPlaceEnv(), KukaPickAndPlaceEnv(start_in_hand=0.0)
    np.testing.assert_array_equal(rollout(plain, seed=4, n=5), rollout(off, seed=4, n=5))
    half = KukaPickAndPlaceEnv(start_in_hand=0.5)
    lifted = [half.reset(seed=s)[0]["observation"][FINGER] < MAX_WIDTH / 2 for s in range(40)]
    assert 10 <= sum(lifted) <= 30  # about half of the episodes start held
    with pytest.raises(ValueError, match="start_in_hand"):
        KukaPickAndPlaceEnv(start_in_hand=1.5)
    for env in (plain, off, half):
        env.close()
