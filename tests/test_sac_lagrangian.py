"""SACLagrangian: cost replay buffer, cost critic, multiplier, the actor trade-off, save/load (small seeded budgets)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3 import SAC

from sbagents.constrained import CostReplayBuffer, PIDLagrangeMultiplier, SACLagrangian
from tests.cli_helpers import cli

th.set_num_threads(1)


class SpeedBandit(gym.Env[np.ndarray, np.ndarray]):
    """One-step episodes: action ``a`` in [-1, 1], reward ``10 * a`` (faster is better), cost ``4 * max(a, 0)**2``.

    Unconstrained, the best action is 1 (cost 4); under an episode-cost limit of 1 it is 0.5 (cost 1, reached at
    the multiplier 2.5).
    """

    observation_space = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
    action_space = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        return np.zeros(1, dtype=np.float32), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        a = float(np.clip(action[0], -1.0, 1.0))
        return np.zeros(1, dtype=np.float32), 10.0 * a, True, False, {"cost": 4.0 * max(a, 0.0) ** 2}


class ConstantCost(gym.Wrapper[Any, Any, Any, Any]):
    """Adds ``info["cost"] = 1`` to every step."""

    def step(self, action: Any) -> Any:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, {**info, "cost": 1.0}


def small(**kwargs: Any) -> dict[str, Any]:
    return {"learning_starts": 50, "batch_size": 64, "seed": 0, "device": "cpu",
            "policy_kwargs": {"net_arch": [32, 32]}, **kwargs}


def test_cost_critic_learns_a_constant_cost() -> None:
    env = ConstantCost(gym.make("Pendulum-v1"))
    model = SACLagrangian("MlpPolicy", env, cost_limit=1000.0, cost_gamma=0.5, **small(tau=0.2, learning_rate=3e-3))
    model.learn(300)
    assert isinstance(model.replay_buffer, CostReplayBuffer)
    assert np.all(model.replay_buffer.costs[: model.replay_buffer.pos] == 1.0)
    data = model.replay_buffer.sample(256)
    q_c = model.predict_cost_values(data.observations, data.actions)
    assert q_c.shape == (256, 1)
    assert abs(float(q_c.mean().detach()) - 2.0) < 0.3  # 1 / (1 - 0.5)


@pytest.mark.parametrize(("limit", "rises"), [(0.1, True), (1000.0, False)])
def test_multiplier_follows_the_episode_cost(limit: float, rises: bool) -> None:
    env = ConstantCost(gym.make("Pendulum-v1", max_episode_steps=25))
    model = SACLagrangian("MlpPolicy", env, cost_limit=limit, multiplier_kwargs={"lr": 0.01}, **small())
    model.learn(150)
    history = model.multiplier.history
    assert history and all(h["ep_cost"] == 25.0 for h in history)
    assert list(model.ep_cost_buffer) == [25.0] * 6
    if rises:
        assert model.multiplier.value > 0 and np.all(np.diff([h["multiplier"] for h in history]) > 0)
    else:
        assert model.multiplier.value == 0.0


def test_constraint_options_are_checked() -> None:
    env = SpeedBandit()
    model = SACLagrangian("MlpPolicy", env, cost_limit=1.0, constraint="pid", multiplier_kwargs={"kp": 0.2})
    assert isinstance(model.multiplier, PIDLagrangeMultiplier) and model.multiplier.kp == 0.2
    assert (model.constraint, model.cost_limit) == ("pid", 1.0)
    with pytest.raises(ValueError, match="constraint"):
        SACLagrangian("MlpPolicy", env, constraint="penalty")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="CostReplayBuffer"):
        SACLagrangian("MlpPolicy", env, replay_buffer_class=CostReplayBuffer.__base__)


def test_save_load_round_trip(tmp_path: Path) -> None:
    env = SpeedBandit()
    model = SACLagrangian("MlpPolicy", env, cost_limit=0.5, multiplier_kwargs={"lr": 0.01}, **small())
    model.learn(100)
    model.save(tmp_path / "model")
    loaded = SACLagrangian.load(tmp_path / "model", env=env, device="cpu")
    for name in ("cost_critic", "cost_critic_target"):
        for a, b in zip(getattr(model, name).parameters(), getattr(loaded, name).parameters(), strict=True):
            assert th.equal(a, b)
    assert loaded.multiplier.value == model.multiplier.value > 0
    assert loaded.multiplier.history == model.multiplier.history
    assert (loaded.cost_limit, loaded.constraint) == (0.5, "lagrangian")
    obs = np.zeros((1, 1), dtype=np.float32)
    assert np.allclose(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    loaded.learn(50, reset_num_timesteps=False)  # the hook is registered on the loaded actor's optimizer
    assert loaded.num_timesteps == 150 and len(loaded.multiplier.history) > len(model.multiplier.history)


def greedy_cost(model: SAC) -> float:
    action = model.predict(np.zeros((1, 1), dtype=np.float32), deterministic=True)[0]
    return 4.0 * max(float(action.ravel()[0]), 0.0) ** 2


@pytest.mark.slow  # learning (~10 s here)
def test_lagrangian_respects_the_limit_where_sac_does_not() -> None:
    sac = SAC("MlpPolicy", SpeedBandit(), **small(learning_rate=1e-2))
    sac.learn(400)
    lag = SACLagrangian("MlpPolicy", SpeedBandit(), cost_limit=1.0, multiplier_kwargs={"lr": 0.05},
                        **small(learning_rate=1e-2))
    lag.learn(400)
    assert greedy_cost(sac) > 2.5  # full speed, a ~ 1
    assert 0.5 < greedy_cost(lag) <= 1.25  # a ~ 0.5: at the limit, not far below it
    assert 1.5 < lag.multiplier.value < 4.0  # near the saddle point's 2.5


def test_train_cli_trains_sac_lagrangian_and_evaluate_loads_it(tmp_path: Path) -> None:
    """``train --algo sac --constraint lagrangian`` on the Kuka path zone (ready pose: the warm-up's random moves
    enter the zone), then ``evaluate --json`` on the saved SACLagrangian."""
    env = ["--env", "sbagents/RobustPickAndPlace-v0"]
    trained = cli("train", "--algo", "sac", *env, "-n", "200", "--seed", "0", "--eval-freq", "0", "-f", str(tmp_path),
                  "--env-kwargs", "control:ee", "safety_zone:path", "zone_mode:cost",
                  "initial_joints:[0.0,0.6,0.0,-1.4,0.0,1.1]", "-params", "learning_starts:100",
                  "--constraint", "lagrangian", "--cost-limit", "1")
    assert trained.returncode == 0, trained.stderr
    line = next(x for x in trained.stdout.splitlines() if x.startswith("constraint (lagrangian): cost limit 1 "))
    assert " in training (recent episodes' mean cost " in line and "; multiplier " in line, line
    run_dir = next((tmp_path / "sac").iterdir())
    history = json.loads((run_dir / "safety.json").read_text())["constraint"]["history"]
    assert history and history[0]["ep_cost"] > 1 and history[0]["multiplier"] > 0
    model = SACLagrangian.load(run_dir / "sbagents_RobustPickAndPlace-v0.zip", device="cpu")
    assert model.multiplier.history == history
    evaluated = cli("evaluate", "--algo", "sac", *env, "-f", str(tmp_path), "-n", "1", "--json")
    assert evaluated.returncode == 0, evaluated.stderr
    assert "mean_cost" in json.loads(evaluated.stdout.strip().splitlines()[-1])
