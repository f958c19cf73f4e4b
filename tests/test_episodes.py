"""The episode record and runner (:mod:`sbagents.callbacks.episodes`) on tiny scripted envs: every field of
:class:`EpisodeRecord` (return, length, success, cost, violations, per-agent returns, declared metrics, game
outcome), the spread of episodes over a VecEnv's copies, Monitor's episodes, and the one aggregation."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv

from sbagents.callbacks.episodes import (
    ILLEGAL_KEY,
    RETURN_KEY,
    SEAT_KEY,
    UNPLAYED_KEY,
    EpisodeRecord,
    GameOutcome,
    game_rates,
    play_env_episodes,
    play_episodes,
    stateless,
    summarize_records,
)


class Scripted(gym.Env[np.ndarray, int]):
    """``length`` steps of reward ``reward``; step 2 costs 0.5, step 3 is a named violation; the last step reports
    ``is_success`` (when ``success`` is not None) and the episode attribute ``size``."""

    observation_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = spaces.Discrete(2)

    def __init__(self, length: int = 3, reward: float = 1.0, success: bool | None = True, costs: bool = True) -> None:
        self.length, self.reward, self.success, self.costs = length, reward, success, costs
        self.t = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(1, np.float32), {}

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self.t += 1
        info: dict[str, Any] = {}
        if self.costs and self.t == 2:
            info["cost"] = 0.5
        if self.costs and self.t == 3:
            info["violation"] = "hazard"
        done = self.t >= self.length
        if done:
            info["size"] = float(self.length)
            if self.success is not None:
                info["is_success"] = self.success
        return np.zeros(1, np.float32), self.reward, done, False, info


def zeros(obs: np.ndarray, state: Any, episode_start: np.ndarray) -> tuple[np.ndarray, Any]:
    return np.zeros(len(obs), dtype=np.int64), None


def test_a_plain_episode_records_return_length_success_cost_and_info() -> None:
    venv = DummyVecEnv([lambda: Scripted(length=4, reward=0.5)])
    (record,) = play_episodes(venv, zeros, 1, seed=0)
    assert (record.ret, record.length, record.success) == (2.0, 4, True)
    assert (record.cost, record.violations) == (1.5, 2)  # 0.5 at step 2, 1.0 for the named violation at step 3
    assert record.info["size"] == 4.0 and record.agent_returns is None and record.game is None
    assert record.metrics == {}
    with pytest.raises(AttributeError):
        record.ret = 0.0  # type: ignore[misc]  # frozen


def test_no_cost_key_no_success_key_means_none() -> None:
    venv = DummyVecEnv([lambda: Scripted(success=None, costs=False)])
    (record,) = play_episodes(venv, zeros, 1)
    assert record.success is None and record.cost is None and record.violations == 0
    summary = summarize_records([record])
    assert summary["success_rate"] is None and "mean_cost" not in summary


def test_episodes_are_spread_over_the_copies_in_completion_order() -> None:
    venv = DummyVecEnv([lambda: Scripted(length=2), lambda: Scripted(length=5)])
    records = play_episodes(venv, zeros, 5)
    # copy 0 runs (5 + 0) // 2 = 2 episodes, copy 1 runs 3; the short ones finish first
    assert [r.length for r in records] == [2, 2, 5, 5, 5]


def test_episode_metrics_hook_sees_the_step_infos_of_its_episode() -> None:
    seen: list[int] = []

    def metrics(infos: list[dict[str, Any]]) -> dict[str, float]:
        seen.append(len(infos))
        return {"costly_steps": float(sum("cost" in i for i in infos))}

    records = play_episodes(DummyVecEnv([lambda: Scripted(length=3)]), zeros, 2, episode_metrics=metrics)
    assert seen == [3, 3] and [r.metrics for r in records] == [{"costly_steps": 1.0}] * 2


class ScaleReward(gym.RewardWrapper[np.ndarray, int]):
    def reward(self, reward: float) -> float:
        return 10.0 * reward


def test_monitor_episodes_take_monitors_return() -> None:
    venv = DummyVecEnv([lambda: ScaleReward(Monitor(Scripted(length=3, reward=1.0)))])
    (summed,) = play_episodes(venv, zeros, 1)
    (monitored,) = play_episodes(venv, zeros, 1, monitor_episodes=True)
    assert summed.ret == 30.0 and monitored.ret == 3.0 and monitored.length == 3


class TwoAgentVec(VecEnv):
    """A team VecEnv of one copy with agents ``a`` and ``b`` (slots 0 and 1): ``a`` earns 1 a step, ``b`` 2; the
    team episode ends after 3 steps with SB3's ``episode`` info (and a declared metric) on the first slot."""

    possible_agents = ("a", "b")
    render_mode = None

    def __init__(self) -> None:
        super().__init__(2, spaces.Box(-1.0, 1.0, (1,), np.float32), spaces.Discrete(2))
        self.t = 0

    def reset(self) -> np.ndarray:
        self.t = 0
        return np.zeros((2, 1), np.float32)

    def step_async(self, actions: np.ndarray) -> None:
        self.t += 1

    def step_wait(self) -> Any:
        infos: list[dict[str, Any]] = [{}, {"cost": 0.25}]
        done = self.t == 3
        if done:
            infos[0]["episode"] = {"r": 9.0, "l": 3, "t": 0.0, "treasures": 2}
            infos[0]["is_success"] = False
            self.t = 0
        return np.zeros((2, 1), np.float32), np.array([1.0, 2.0], np.float32), np.array([done, done]), infos

    def close(self) -> None:
        pass

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        return [getattr(self, attr_name)] * 2

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *args: Any, indices: Any = None, **kwargs: Any) -> list[Any]:
        return []

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        return [False, False]

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        return [seed, seed]


def test_a_team_episode_records_per_agent_returns_and_declared_metrics() -> None:
    records = play_episodes(TwoAgentVec(), stateless(lambda obs: np.zeros(len(obs), np.int64)), 2)
    assert len(records) == 2
    first = records[0]
    assert first.agent_returns == {"a": 3.0, "b": 6.0} and first.ret == 9.0 and first.length == 3
    assert first.metrics == {"treasures": 2.0} and first.success is False
    assert first.cost == pytest.approx(0.75) and first.violations == 3
    summary = summarize_records(records, {"left": ["a"], "right": ["b"]})
    assert summary["metrics"] == {"episode_length": 3.0, "per_agent_return": {"a": 3.0, "b": 6.0},
                                  "per_group_return": {"left": 3.0, "right": 6.0}, "treasures": 2.0}
    assert summary["success_rate"] == 0.0 and summary["mean_cost"] == pytest.approx(0.75)


class Game(gym.Env[np.ndarray, int]):
    """A scripted game: every reset first reports one game that ended before the player moved (seat 1, return -1);
    then the player plays 2 moves (the first illegal) and wins from seat 0 (return 1, step rewards summing to 0.5:
    the game's return is the info's, not the sum)."""

    observation_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = spaces.Discrete(2)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(1, np.float32), {SEAT_KEY: 0, UNPLAYED_KEY: [(1, -1.0)]}

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self.t += 1
        info: dict[str, Any] = {ILLEGAL_KEY: int(self.t == 1)}
        if self.t == 2:
            info.update({SEAT_KEY: 0, RETURN_KEY: 1.0, "is_success": True})
        return np.zeros(1, np.float32), 0.25, self.t == 2, False, info


def test_a_game_records_its_outcome_and_the_games_ended_at_a_reset() -> None:
    records = play_env_episodes(Game(), stateless(lambda obs: 0), 3, seed=0)
    assert [r.game for r in records] == [GameOutcome(1, -1.0), GameOutcome(0, 1.0, 1), GameOutcome(1, -1.0)]
    assert [(r.ret, r.length) for r in records] == [(-1.0, 0), (1.0, 2), (-1.0, 0)]
    assert records[1].success is True
    rates = game_rates(records)
    assert rates["n_games"] == 3 and rates["win_rate"] == pytest.approx(1 / 3)
    assert rates["loss_rate"] == pytest.approx(2 / 3) and rates["draw_rate"] == 0.0


def test_the_aggregation_keys() -> None:
    records = [EpisodeRecord(1.0, 2, True, cost=1.0, metrics={"m": 1.0}), EpisodeRecord(3.0, 4, None)]
    summary = summarize_records(records)
    assert summary == {"n_episodes": 2, "mean_return": 2.0, "std_return": 1.0, "mean_length": 3.0,
                       "success_rate": 1.0, "metrics": {"m": 1.0}, "mean_cost": 1.0}
    assert game_rates(records)["n_games"] == 0


def test_the_runner_module_stays_low() -> None:
    import subprocess

    code = ("import sys, sbagents.callbacks.episodes, sbagents.callbacks.safety; "
            "print(sorted(m for m in ('pettingzoo', 'sbagents.pipeline', 'sbagents.multiagent') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_bad_counts_are_refused() -> None:
    with pytest.raises(ValueError, match="n_episodes must be >= 1"):
        play_episodes(DummyVecEnv([Scripted]), zeros, 0)
    with pytest.raises(ValueError, match="n_episodes must be >= 1"):
        play_env_episodes(Scripted(), stateless(lambda obs: 0), 0)
