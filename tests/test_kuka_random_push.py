"""The push envs' object options and panda-gym's randomized workspace (benchmarks/configs/kuka_random.yml)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3 import HerReplayBuffer

from sbagents.core.experiment import resolve
from sbagents.core.zoo_config import load_yaml, lookup_entry
from sbagents.envs.kuka import KukaPushEnv, PickAndPlaceEnv, PickAndPlaceGoalEnv
from sbagents.envs.kuka.scripted import ScriptedPusher, run_episode
from sbagents.envs.kuka.tasks import BLOCK_HALF_HEIGHT, CUBE_SIZE

CONF = Path(__file__).resolve().parents[1] / "benchmarks" / "configs" / "kuka_random.yml"
GOAL_ID = "sbagents/PickAndPlaceGoal-v0"
#: Entry of the dense Kuka run (one YAML file cannot hold two entries for one id).
DENSE_KEY = GOAL_ID + "-dense"
#: (our entry, panda-gym's entry) trained against each other by ``python -m benchmarks run kuka-learning-random``.
PAIRS = [(GOAL_ID, "PandaPush-v3"), (DENSE_KEY, "PandaPushDense-v3")]


def _kwargs(key: str) -> dict[str, Any]:
    return dict(lookup_entry(CONF, key)["env_kwargs"])


def _make(key: str, **extra: Any) -> KukaPushEnv:
    env = (PickAndPlaceGoalEnv if key.startswith(GOAL_ID) else PickAndPlaceEnv)(**{**_kwargs(key), **extra})
    env.action_space.seed(0)
    return env


def _settle(env: KukaPushEnv, steps: int = 48) -> np.ndarray:
    env.sim.step(steps)
    return env.task.object_position()


def test_defaults_unchanged() -> None:
    env = PickAndPlaceEnv()
    env.reset(seed=0)
    assert env.task.object == "block"
    np.testing.assert_allclose(env.task.object_position(), [0.5, 0.0, BLOCK_HALF_HEIGHT], atol=1e-6)
    np.testing.assert_allclose(env.task.target, [0.5, 0.5, BLOCK_HALF_HEIGHT])
    env.close()
    with pytest.raises(ValueError, match="object must be one of"):
        PickAndPlaceEnv(object="sphere")


def test_cube_rests_at_its_half_size_and_keeps_scale_and_mass() -> None:
    env = PickAndPlaceEnv(object="cube", object_xy=(0.6, 0.1))
    env.reset(seed=1)
    np.testing.assert_allclose(_settle(env), [0.6, 0.1, CUBE_SIZE / 2], atol=1e-3)
    low, high = env.sim.client.getAABB(env.task.block)
    np.testing.assert_allclose(np.subtract(high, low), [CUBE_SIZE] * 3, atol=2e-3)  # a cube, not the stick
    assert env.task.target[2] == pytest.approx(CUBE_SIZE / 2)
    env.close()
    env = PickAndPlaceEnv(object="cube", scale_range=(0.5, 1.5), mass_range=(0.1, 1.0))
    scales = set()
    for seed in range(4):
        _, info = env.reset(seed=seed)
        half = CUBE_SIZE / 2 * info["object_scale"]
        scales.add(round(info["object_scale"], 6))
        assert env.task.target[2] == pytest.approx(half)
        assert _settle(env)[2] == pytest.approx(half, abs=1e-3)
        low, high = env.sim.client.getAABB(env.task.block)
        assert high[2] - low[2] == pytest.approx(2 * half, abs=2e-3)
        assert env.sim.client.getDynamicsInfo(env.task.block, -1)[0] == pytest.approx(info["object_mass"])
    assert len(scales) == 4
    env.close()


@pytest.mark.parametrize("key", [GOAL_ID, DENSE_KEY, "sbagents/PickAndPlace-v0"])
def test_start_and_target_fill_their_squares(key: str) -> None:
    kwargs = _kwargs(key)
    centre, r = np.asarray(kwargs["object_xy"]), kwargs["object_range"]
    box = np.asarray(kwargs["target_box"])
    env = _make(key)
    starts, targets = [], []
    for seed in range(200):
        env.reset(seed=seed)
        starts.append(env.task.object_position()[:2])
        targets.append(env.task.target[:2])
    env.close()
    starts_a, targets_a = np.array(starts), np.array(targets)
    for points, lo, hi in ((starts_a, centre - r, centre + r), (targets_a, box[0], box[1])):
        assert np.all(points >= lo - 1e-9) and np.all(points <= hi + 1e-9)
        assert np.all(points.min(axis=0) < lo + 0.02) and np.all(points.max(axis=0) > hi - 0.02)  # spans it
    assert np.linalg.norm(starts_a - targets_a, axis=1).max() > 0.3  # drawn independently, as panda-gym's


def test_seeding_is_deterministic() -> None:
    runs = []
    for _ in range(2):
        env = _make(GOAL_ID)
        obs, _ = env.reset(seed=7)
        trace = [obs["observation"], obs["desired_goal"]]
        rng = np.random.default_rng(0)
        for _ in range(5):
            obs, *_ = env.step(rng.uniform(-1, 1, 3).astype(np.float32))
            trace.append(obs["observation"])
        runs.append(np.concatenate(trace))
        env.close()
    np.testing.assert_array_equal(runs[0], runs[1])


@pytest.mark.parametrize("key", [GOAL_ID, "sbagents/PickAndPlace-v0"])
def test_cube_env_passes_check_env(key: str) -> None:
    env = _make(key)
    check_env(env, skip_render_check=True)
    env.close()


@pytest.mark.parametrize(("key", "steps"), [(GOAL_ID, 50), ("sbagents/PickAndPlace-v0", 100)])
def test_scripted_pusher_solves_the_randomized_workspace(key: str, steps: int) -> None:
    env = _make(key)
    assert env.max_steps == steps
    controller = ScriptedPusher(env)
    results = [run_episode(env, controller, seed=seed) for seed in range(20)]
    env.close()
    assert sum(r["is_success"] for r in results) >= 18
    assert all(r["cost"] == 0 for r in results)


def test_config_entries_load_and_pairs_match() -> None:
    data = load_yaml(CONF)
    ours = [key for key in data if key.startswith("sbagents/")]
    assert set(ours) == {GOAL_ID, DENSE_KEY, "sbagents/PickAndPlace-v0"}
    for key in ours:
        env_id = GOAL_ID if key == DENSE_KEY else key
        exp = resolve("sac", env_id, lookup_entry(CONF, key), f"kuka_random.yml:{key}")
        assert exp.algo_kwargs["policy_kwargs"]["net_arch"] == [64, 64]
        assert exp.env_kwargs["object"] == "cube" and exp.env_kwargs["object_range"] == 0.15
        box = np.asarray(exp.env_kwargs["target_box"])
        np.testing.assert_allclose(box.mean(axis=0), exp.env_kwargs["object_xy"])  # same centre ...
        np.testing.assert_allclose(box[1] - box[0], [0.3, 0.3])  # ... and width as panda-gym's squares
        env = gym.make(env_id, **exp.env_kwargs)
        assert env.unwrapped.task.distance_threshold == 0.05  # type: ignore[attr-defined]
        env.close()
        if key != "sbagents/PickAndPlace-v0":
            assert exp.env_kwargs["max_steps"] == 50 and exp.policy == "MultiInputPolicy"
    for ours_key, panda_key in PAIRS:
        mine, theirs = dict(data[ours_key]), dict(data[panda_key])
        assert mine.pop("env_kwargs")["reward_type"] == ("sparse" if ours_key == GOAL_ID else "dense")
        assert mine == theirs  # the same hyperparameters within a pair
        her = resolve("sac", GOAL_ID, mine, ours_key).algo_kwargs.get("replay_buffer_class")
        assert (her is HerReplayBuffer) == (ours_key == GOAL_ID)
        if her is not None:
            assert mine["replay_buffer_kwargs"] == {"goal_selection_strategy": "future", "n_sampled_goal": 4}
