"""HazardGridWorld against its specification (docs/envs.md): layout, rewards, costs, termination vs truncation,
the fixed-penalty variant, checkers; and ``mean_cost`` in evaluation summaries of envs with a cost."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sbagents  # noqa: F401  (registers the ids)
from sbagents.envs.hazard_gridworld import HazardGridWorldEnv
from sbagents.pipeline.evaluation import summarize

UP, DOWN, LEFT, RIGHT = 0, 1, 2, 3
SHORT_PATH = [RIGHT] * 6
SAFE_PATH = [RIGHT, RIGHT, UP, UP, UP, UP, RIGHT, RIGHT, DOWN, DOWN, DOWN, DOWN, RIGHT, RIGHT]


def play(env: gym.Env, actions: list[int]) -> tuple[float, float, list[dict], bool, bool]:
    env.reset(seed=0)
    total = cost = 0.0
    infos = []
    terminated = truncated = False
    for action in actions:
        _, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        cost += info["cost"]
        infos.append(info)
    return total, cost, infos, terminated, truncated


def test_layout_and_the_two_paths() -> None:
    env = gym.make("sbagents/HazardGridWorld-v0", render_mode="ansi")
    obs, _ = env.reset(seed=0)
    assert obs == 4 * 7 + 0 and env.observation_space == gym.spaces.Discrete(35)
    assert env.render().split("\n")[4] == "A . . H . . G"
    total, cost, infos, terminated, truncated = play(env, SHORT_PATH)
    assert (total, cost, terminated, truncated) == (95.0, 1.0, True, False)
    assert [i["violation"] for i in infos] == [None, None, "hazard", None, None, None]
    assert infos[-1]["is_success"] is True
    total, cost, infos, terminated, _ = play(env, SAFE_PATH)
    assert (total, cost, terminated) == (87.0, 0.0, True)
    assert all(i["violation"] is None and i["cost"] == 0.0 for i in infos)


def test_hazards_do_not_end_episodes_and_cost_every_step_on_them() -> None:
    env = HazardGridWorldEnv(max_steps=6)
    total, cost, infos, terminated, truncated = play(env, [RIGHT, RIGHT, RIGHT, UP, UP, DOWN])
    assert cost == 4.0 and [i["cost"] for i in infos] == [0.0, 0.0, 1.0, 1.0, 1.0, 1.0]
    assert total == -6.0 and not terminated and truncated and infos[-1]["is_success"] is False


def test_fixed_penalty_variant_adds_to_the_reward() -> None:
    env = gym.make("sbagents/HazardGridWorld-v0", hazard_penalty=-50.0)
    total, cost, _, _, _ = play(env, SHORT_PATH)
    assert (total, cost) == (45.0, 1.0)  # 95 - 50: the safe path (87) is now the better one


def test_walls_custom_layout_and_bad_arguments() -> None:
    env = HazardGridWorldEnv(size=3, start=(0, 0), goal=(2, 2), hazards=[(1, 1)], max_steps=10)
    total, cost, infos, _, _ = play(env, [UP, DOWN, RIGHT])
    assert infos[0]["event"] == "wall" and cost == 1.0 and total == -3.0
    for kwargs, message in [({"hazards": [(4, 6)]}, "hazards must not be"), ({"hazards": [(9, 9)]}, "outside"),
                            ({"hazard_penalty": 5.0}, "hazard_penalty"), ({"hazards": "ab"}, "list of"),
                            ({"hazard_penalty": float("nan")}, "hazard_penalty")]:
        with pytest.raises(ValueError, match=message):
            HazardGridWorldEnv(**kwargs)


def test_checkers_seeding_and_rendering() -> None:
    gym_check_env(gym.make("sbagents/HazardGridWorld-v0").unwrapped)
    sb3_check_env(HazardGridWorldEnv())
    a, b = HazardGridWorldEnv(), HazardGridWorldEnv()
    rng = np.random.default_rng(0)
    assert a.reset(seed=3) == b.reset(seed=3)
    for action in rng.integers(0, 4, 60):
        assert a.step(int(action)) == b.step(int(action)) or a.steps > a.max_steps
        if a.steps >= a.max_steps:
            break
    frame = HazardGridWorldEnv(render_mode="rgb_array")
    frame.reset()
    image = frame.render()
    assert image.shape == (160, 224, 3) and tuple(image[1 * 32 + 16, 3 * 32 + 16]) == (240, 150, 40)


def test_summary_reports_mean_cost_only_for_envs_with_costs() -> None:
    with_cost = summarize("x", "ppo", [1.0, 3.0], [5, 5], [], {}, costs=[1.0, 0.0])
    assert with_cost["mean_cost"] == 0.5
    assert "mean_cost" not in summarize("x", "ppo", [1.0], [5], [], {})
