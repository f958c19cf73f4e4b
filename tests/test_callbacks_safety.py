"""SafetyViolationCallback: counts equal the env's own tally, logging, limits, safety.json."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces
from stable_baselines3 import A2C, DQN, PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import configure

from sbagents.callbacks import SafetyViolationCallback, step_violation

torch.set_num_threads(1)


class ViolationEnv(gym.Env[np.ndarray, np.int64]):
    """Deterministic test env that keeps its own tally of the violations it reports.

    Episodes of ``length`` steps. Action 1 enters a "zone" (``violation="zone"``, cost 1); every 4th step
    of an episode is "speeding" (``violation="speeding"``, cost 2) whatever the action; every 7th step
    has ``cost=0.5`` without a named violation. Reward: 1 for action 0, else 0; ``is_success`` at the end
    when no zone step happened. ``info`` carries episode attributes ``group`` and ``size`` (drawn at reset).
    """

    attribute_ranges = {"size": (0.0, 1.0)}

    def __init__(self, length: int = 10) -> None:
        self.length = length
        self.observation_space = spaces.Box(0.0, 1.0, (2,), dtype=np.float32)
        self.action_space = spaces.Discrete(2)
        self.tally: dict[str, int] = {"zone": 0, "speeding": 0, "cost": 0}
        self.cost_total = 0.0
        self.t = 0
        self.zone_steps = 0
        self.group, self.size = 0, 0.0

    def _obs(self) -> np.ndarray:
        return np.array([self.t / self.length, self.size], dtype=np.float32)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self.t, self.zone_steps = 0, 0
        self.group = int(self.np_random.integers(0, 3))
        self.size = float(self.np_random.uniform(0.0, 1.0))
        return self._obs(), {"group": self.group, "size": self.size}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self.t += 1
        info: dict[str, Any] = {"group": self.group, "size": self.size, "violation": None, "cost": 0.0}
        if int(action) == 1:
            info.update(violation="zone", cost=1.0)
            self.zone_steps += 1
        elif self.t % 4 == 0:
            info.update(violation="speeding", cost=2.0)
        elif self.t % 7 == 0:
            info.update(cost=0.5)
        kind = info["violation"] or ("cost" if info["cost"] > 0 else None)
        if kind:
            self.tally[kind] += 1
        self.cost_total += info["cost"]
        truncated = self.t >= self.length
        if truncated:
            info["is_success"] = self.zone_steps == 0
        return self._obs(), float(int(action) == 0), False, truncated, info


def test_step_violation_contract() -> None:
    assert step_violation({}) == (None, 0.0)
    assert step_violation({"violation": None, "cost": 0.0}) == (None, 0.0)
    assert step_violation({"violation": "safety_zone"}) == ("safety_zone", 1.0)
    assert step_violation({"violation": "safety_zone", "cost": 1.0}) == ("safety_zone", 1.0)
    assert step_violation({"cost": 0.3}) == ("cost", 0.3)


@pytest.mark.parametrize("algo", [PPO, DQN])
def test_counts_equal_env_tally_and_are_logged(tmp_path: Path, algo: Any) -> None:
    env = make_vec_env(ViolationEnv, n_envs=3, seed=0)
    kwargs = {"n_steps": 20, "batch_size": 60} if algo is PPO else {"learning_starts": 10}
    model = algo("MlpPolicy", env, seed=0, policy_kwargs={"net_arch": [16]}, **kwargs)
    model.set_logger(configure(str(tmp_path / "log"), ["csv"]))
    cb = SafetyViolationCallback(path=tmp_path, verbose=0)
    model.learn(600, log_interval=1, callback=cb)
    tallies = env.get_attr("tally")
    expected = {k: sum(t[k] for t in tallies) for k in ("zone", "speeding", "cost")}
    assert {k: cb.counts.get(k, 0) for k in expected} == expected
    assert cb.total_steps == model.num_timesteps
    assert cb.total_cost == pytest.approx(sum(env.get_attr("cost_total")))
    assert len(cb.ep_costs) == model.num_timesteps // 10  # 10-step episodes, all finished
    data = json.loads((tmp_path / "safety.json").read_text())
    assert data["violations"] == {k: v for k, v in expected.items() if v}
    assert data["total_steps"] == model.num_timesteps and data["stopped"] is False
    assert data["violation_rate"] == pytest.approx(1000 * sum(expected.values()) / model.num_timesteps)
    assert data["ep_cost"]["mean"] == pytest.approx(np.mean(cb.ep_costs))
    with open(tmp_path / "log" / "progress.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    logged = [r for r in rows if r.get("safety/violations")]
    assert logged and float(logged[-1]["safety/violations"]) <= sum(expected.values())
    assert "safety/ep_cost" in rows[-1] and "safety/violation_rate" in rows[-1]


def test_max_violations_stops_training(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    env = make_vec_env(ViolationEnv, n_envs=2, seed=0)
    model = A2C("MlpPolicy", env, n_steps=5, seed=0, policy_kwargs={"net_arch": [16]})
    cb = SafetyViolationCallback(max_violations=20, path=tmp_path / "out" / "s.json")
    model.learn(5_000, callback=cb)
    assert model.num_timesteps < 200 and cb.stopped and cb.total_violations == 21
    assert "max_violations 20" in capsys.readouterr().out
    data = json.loads((tmp_path / "out" / "s.json").read_text())
    assert data["stopped"] is True and "max_violations" in data["stop_reason"]


def test_cost_limit_stops_on_mean_episode_cost(tmp_path: Path) -> None:
    env = make_vec_env(ViolationEnv, n_envs=2, seed=0)
    model = PPO("MlpPolicy", env, n_steps=10, batch_size=20, seed=0, policy_kwargs={"net_arch": [16]})
    # each 10-step episode costs >= 4.5 (speeding or zone at steps 4 and 8, cost 0.5 or zone at step 7)
    cb = SafetyViolationCallback(cost_limit=1.0, min_episodes=3, path=tmp_path, verbose=0)
    model.learn(5_000, callback=cb)
    # both envs end their 2nd episode at vec step 20: the limit is checked with 4 episodes done
    assert cb.stopped and model.num_timesteps == 40 and len(cb.ep_costs) == 4
    assert min(cb.ep_costs) >= 4.5 and "cost_limit 1" in (cb.stop_reason or "")
    assert json.loads((tmp_path / "safety.json").read_text())["episodes"] == 4


def test_kuka_violations_match_info(tmp_path: Path) -> None:
    from sbagents.envs import kuka
    seen: list[int] = []

    class Count(gym.Wrapper):
        def step(self, action: Any) -> Any:
            out = self.env.step(action)
            seen.append(int(bool(out[4].get("violation"))))
            return out

    env = make_vec_env(lambda: Count(kuka.RobustPickAndPlaceEnv(max_steps=20)), n_envs=1, seed=0)
    model = A2C("MlpPolicy", env, n_steps=10, seed=0, policy_kwargs={"net_arch": [16]})
    cb = SafetyViolationCallback(path=tmp_path, verbose=0)
    model.learn(60, callback=cb)
    env.close()
    assert len(seen) == cb.total_steps == 60
    assert cb.counts.get("safety_zone", 0) == sum(seen)
