"""VecNormalize statistics files when only rewards are scaled (``normalize: {norm_obs: false, norm_reward: true}``):
SB3 keeps no observation statistics then, and saving, loading, evaluating and exporting such a run work."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from sbagents.state_files import load_vecnormalize, save_vecnormalize
from tests.cli_helpers import cli


def test_reward_only_statistics_round_trip(tmp_path: Path) -> None:
    venv = VecNormalize(DummyVecEnv([lambda: gym.make("CartPole-v1")]), norm_obs=False, norm_reward=True)
    venv.reset()
    for _ in range(50):
        venv.step(np.array([venv.action_space.sample()]))
    assert not hasattr(venv, "obs_rms")
    path = save_vecnormalize(venv, tmp_path / "vecnormalize.npz")
    loaded = load_vecnormalize(path, DummyVecEnv([lambda: gym.make("CartPole-v1")]))
    assert not loaded.norm_obs and loaded.norm_reward
    np.testing.assert_array_equal(loaded.ret_rms.var, venv.ret_rms.var)
    assert loaded.ret_rms.count == venv.ret_rms.count > 1


def test_a_reward_scaled_team_run_trains_evaluates_and_exports(tmp_path: Path) -> None:
    common = ["--algo", "ppo", "--env", "mpe2.simple_spread_v3", "-f", str(tmp_path)]
    train = cli("train", *common, "-n", "500", "--eval-freq", "0", "--final-eval-episodes", "0", "-params",
                "n_envs:2", "n_steps:25", "batch_size:50", "n_epochs:1",
                "normalize:{norm_obs: false, norm_reward: true}")
    assert train.returncode == 0, train.stderr
    assert (next((tmp_path / "ppo").iterdir()) / "vecnormalize.npz").exists()
    evaluated = cli("evaluate", *common, "-n", "2", "--json")
    assert evaluated.returncode == 0, evaluated.stderr
    assert '"mean_return"' in evaluated.stdout
    exported = cli("export", *common)
    assert exported.returncode == 0, exported.stderr
