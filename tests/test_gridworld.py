"""GridWorld against its specification (docs/envs.md), transition by transition."""

from __future__ import annotations

import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sbagents  # noqa: F401  (registers the ids)
from sbagents.envs.gridworld import GridWorldEnv

UP, DOWN, LEFT, RIGHT = 0, 1, 2, 3


def at(env: GridWorldEnv, cell: tuple[int, int]) -> GridWorldEnv:
    env.reset(seed=0)
    env.agent = cell
    return env


@pytest.fixture
def env() -> GridWorldEnv:
    return GridWorldEnv()


def test_spaces_and_start(env: GridWorldEnv) -> None:
    assert env.observation_space == gym.spaces.Discrete(25)
    assert env.action_space == gym.spaces.Discrete(4)
    obs, info = env.reset(seed=123)
    assert obs == 0 and info == {}
    assert env.goal == (4, 4) and env.obstacles == {(1, 1), (2, 2), (3, 3)}


@pytest.mark.parametrize(
    ("cell", "action", "expected"),
    [((2, 0), UP, (1, 0)), ((0, 2), DOWN, (1, 2)), ((0, 2), LEFT, (0, 1)), ((0, 2), RIGHT, (0, 3))],
)
def test_action_deltas(env: GridWorldEnv, cell: tuple[int, int], action: int, expected: tuple[int, int]) -> None:
    at(env, cell)
    obs, reward, *_ = env.step(action)
    assert env.agent == expected and reward == -1.0
    assert obs == expected[0] * 5 + expected[1]


@pytest.mark.parametrize(("cell", "action"), [((0, 0), UP), ((0, 0), LEFT), ((4, 0), DOWN), ((0, 4), RIGHT)])
def test_off_grid_costs_one_and_stays(env: GridWorldEnv, cell: tuple[int, int], action: int) -> None:
    at(env, cell)
    obs, reward, terminated, truncated, info = env.step(action)
    assert (reward, terminated, truncated) == (-1.0, False, False)
    assert env.agent == cell and obs == cell[0] * 5 + cell[1]
    assert info["event"] == "wall"


@pytest.mark.parametrize(("cell", "action"), [((0, 1), DOWN), ((1, 0), RIGHT), ((2, 1), RIGHT), ((3, 2), RIGHT)])
def test_obstacle_costs_ten_and_stays(env: GridWorldEnv, cell: tuple[int, int], action: int) -> None:
    at(env, cell)
    obs, reward, terminated, truncated, info = env.step(action)
    assert (reward, terminated, truncated) == (-10.0, False, False)
    assert env.agent == cell and info["event"] == "obstacle"


def test_free_move_costs_one(env: GridWorldEnv) -> None:
    env.reset(seed=0)
    obs, reward, terminated, truncated, _ = env.step(RIGHT)
    assert (obs, reward, terminated, truncated) == (1, -1.0, False, False)


@pytest.mark.parametrize(("cell", "action"), [((3, 4), DOWN), ((4, 3), RIGHT)])
def test_goal_gives_100_and_terminates(env: GridWorldEnv, cell: tuple[int, int], action: int) -> None:
    at(env, cell)
    obs, reward, terminated, truncated, info = env.step(action)
    assert (obs, reward, terminated, truncated) == (24, 100.0, True, False)
    assert info["is_success"] is True


def test_optimal_return_is_93(env: GridWorldEnv) -> None:
    env.reset(seed=0)
    rewards = [env.step(a)[1] for a in [DOWN] * 4 + [RIGHT] * 4]
    assert len(rewards) == 8 and sum(rewards) == 93


def test_truncation_after_max_steps() -> None:
    env = GridWorldEnv(max_steps=5)
    env.reset(seed=0)
    for i in range(5):
        _, _, terminated, truncated, info = env.step(UP)
        assert not terminated
        assert truncated == (i == 4)
    assert info["is_success"] is False
    env.reset()
    assert env.steps == 0 and env.agent == (0, 0)


def test_gymnasium_time_limit_not_needed_but_registered_id_works() -> None:
    env = gym.make("sbagents/GridWorld-v0", max_steps=3)
    env.reset(seed=0)
    truncs = [env.step(UP)[3] for _ in range(3)]
    assert truncs == [False, False, True]


def test_custom_layout() -> None:
    env = GridWorldEnv(size=(3, 4), start=(2, 0), goal=(0, 3), obstacles=[(1, 1)], max_steps=10)
    assert env.observation_space.n == 12
    obs, _ = env.reset(seed=0)
    assert obs == 8
    with pytest.raises(ValueError, match="outside"):
        GridWorldEnv(goal=(5, 5))
    with pytest.raises(ValueError, match="must not be obstacles"):
        GridWorldEnv(obstacles=[(0, 0)])


def test_invalid_action_raises(env: GridWorldEnv) -> None:
    env.reset(seed=0)
    with pytest.raises(ValueError, match="up, down, left, right"):
        env.step(7)


def test_render_modes() -> None:
    text = GridWorldEnv(render_mode="ansi")
    text.reset(seed=0)
    assert text.render() == "A . . . .\n. X . . .\n. . X . .\n. . . X .\n. . . . G"
    rgb = GridWorldEnv(render_mode="rgb_array")
    rgb.reset(seed=0)
    frame = rgb.render()
    assert isinstance(frame, np.ndarray) and frame.shape == (160, 160, 3) and frame.dtype == np.uint8


def test_human_render_prints(capsys: pytest.CaptureFixture[str]) -> None:
    env = GridWorldEnv(render_mode="human")
    env.reset(seed=0)
    assert "A . . . ." in capsys.readouterr().out


def test_seeding_is_deterministic() -> None:
    a, b = GridWorldEnv(), GridWorldEnv()
    assert a.reset(seed=7) == b.reset(seed=7)
    actions = np.random.default_rng(0).integers(0, 4, 50)
    assert [a.step(int(x))[:4] for x in actions] == [b.step(int(x))[:4] for x in actions]


def test_env_checkers() -> None:
    gym_check_env(GridWorldEnv())
    sb3_check_env(GridWorldEnv(), warn=True)
    gym_check_env(gym.make("sbagents/GridWorld-v0").unwrapped)


def test_make_in_fresh_interpreter_without_import() -> None:
    code = "import gymnasium as gym; e = gym.make('sbagents:sbagents/GridWorld-v0'); print(e.reset(seed=0)[0])"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "0"
