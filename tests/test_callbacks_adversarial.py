"""Observation attacks: spec parsing, eps 0 = clean, the eps ball, PGD vs noise, report and callback."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3 import DQN, PPO, SAC, TD3
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.logger import configure
from stable_baselines3.common.vec_env import VecNormalize

import sbagents  # noqa: F401  (registers the env ids)
from sbagents.callbacks import (
    AdversarialEvalCallback,
    AttackSpec,
    ObservationAttacker,
    adversarial_report,
    evaluate_under_attack,
    parse_attack_spec,
)
from sbagents.callbacks.attacks import _encode
from sbagents.envs.smart_home import SmartHomeEnv

torch.set_num_threads(1)
GRID = "sbagents/GridWorld-v0"


@pytest.fixture(scope="module")
def grid_ppo() -> PPO:
    """PPO that solves GridWorld (return 93) in ~20k steps, a few seconds."""
    env = make_vec_env(GRID, n_envs=8, seed=0)
    model = PPO("MlpPolicy", env, n_steps=64, batch_size=128, learning_rate=1e-3, ent_coef=0.01, seed=0,
                policy_kwargs={"net_arch": [64, 64]})
    model.learn(20_000)
    return model


def test_parse_attack_spec() -> None:
    specs = parse_attack_spec("gaussian:0.05,0.1 fgsm:0.01 pgd:0.1:steps=20,step_size=0.02 none")
    assert [(s.name, s.eps) for s in specs] == [("gaussian", 0.05), ("gaussian", 0.1), ("fgsm", 0.01),
                                                ("pgd", 0.1), ("none", 0.0)]
    assert specs[3].n_steps == 20 and specs[3].alpha == 0.02 and specs[2].n_steps == 1
    assert specs[0].label == "gaussian_0.05"
    assert parse_attack_spec(["uniform:0.2", "critic:0.1"])[1] == AttackSpec("critic", 0.1)
    bad_specs = [("", "empty"), ("foo:0.1", "unknown attack 'foo'"), ("pgd", "expected name:eps"),
                 ("pgd:-1", "eps must be"), ("pgd:x", "could not convert"),
                 ("pgd:0.1:depth=3", "unknown option")]
    for bad, msg in bad_specs:
        with pytest.raises(ValueError, match=msg) as err:
            parse_attack_spec(bad)
        assert "\n" not in str(err.value)


def test_eps_zero_changes_nothing(grid_ppo: PPO) -> None:
    env = make_vec_env(GRID, n_envs=2, seed=3)
    env.seed(5)
    clean, _ = evaluate_policy(grid_ppo, env, n_eval_episodes=4, return_episode_rewards=True)
    for spec in ("none", "gaussian:0", "uniform:0", "fgsm:0", "pgd:0"):
        result = evaluate_under_attack(grid_ppo, env, parse_attack_spec(spec)[0], 4, seed=5)
        assert result["mean_return"] == pytest.approx(np.mean(clean)) and result["max_perturbation"] == 0.0
        assert result["episodes"] == 4 and result["success_rate"] == 1.0

    pend = make_vec_env("Pendulum-v1", n_envs=1, seed=0)
    sac = SAC("MlpPolicy", pend, seed=0, policy_kwargs={"net_arch": [16, 16]})
    pend.seed(1)
    clean, _ = evaluate_policy(sac, pend, n_eval_episodes=1, return_episode_rewards=True)
    for spec in ("pgd:0", "critic:0"):
        result = evaluate_under_attack(sac, pend, parse_attack_spec(spec)[0], 1, seed=1)
        assert result["mean_return"] == pytest.approx(np.mean(clean), rel=1e-6)
        assert np.isnan(result["success_rate"])


def _check_ball(policy: Any, venv: Any, names: tuple[str, ...], eps: float = 0.1) -> None:
    obs = venv.reset()
    space = policy.observation_space
    for name in names:
        attacker = ObservationAttacker(policy, venv, AttackSpec(name, eps), seed=0)
        x = _encode(obs, space)
        xa = attacker.perturb(x)
        delta = (xa - x).abs()
        assert xa.shape == x.shape and float(delta.max()) > 0, name
        assert bool(torch.all(delta <= eps * attacker.scale + 1e-5)), name
        assert bool(torch.all(xa >= attacker.low - 1e-6) and torch.all(xa <= attacker.high + 1e-6)), name
        actions = attacker.act(obs)
        assert venv.action_space.contains(actions[0]), name


def test_perturbations_stay_in_the_eps_ball() -> None:
    home = make_vec_env(SmartHomeEnv, n_envs=4, seed=0)  # raw Box: scale = declared range width
    ppo = PPO("MlpPolicy", home, n_steps=8, batch_size=32, policy_kwargs={"net_arch": [16]})
    _check_ball(ppo.policy, home, ("uniform", "fgsm", "pgd"))
    scale = ObservationAttacker(ppo.policy, home, AttackSpec("pgd", 0.1)).scale
    space = home.observation_space
    assert isinstance(space, gym.spaces.Box)
    assert torch.allclose(scale, torch.as_tensor(space.high - space.low))

    norm = VecNormalize(make_vec_env(SmartHomeEnv, n_envs=4, seed=0))  # normalized space: scale 1
    td3 = TD3("MlpPolicy", norm, policy_kwargs={"net_arch": [16]})
    _check_ball(td3.policy, norm, ("uniform", "fgsm", "pgd", "critic"))
    assert float(ObservationAttacker(td3.policy, norm, AttackSpec("pgd", 0.1)).scale.max()) == 1.0

    grid = make_vec_env(GRID, n_envs=4, seed=0)  # one-hot relaxation, clipped to [0, 1]
    dqn = DQN("MlpPolicy", grid, policy_kwargs={"net_arch": [16]})
    _check_ball(dqn.policy, grid, ("uniform", "fgsm", "pgd", "critic"), eps=0.3)
    ppo_grid = PPO("MlpPolicy", grid, n_steps=8, batch_size=32, policy_kwargs={"net_arch": [16]})
    with pytest.raises(ValueError, match="critic attack needs a Q-function"):
        ObservationAttacker(ppo_grid.policy, grid, AttackSpec("critic", 0.1))


def test_pgd_hurts_more_than_gaussian_noise(grid_ppo: PPO, tmp_path: Path) -> None:
    env = make_vec_env(GRID, n_envs=1, seed=0)
    rows = adversarial_report(grid_ppo, env, "gaussian:0.3 pgd:0.3 fgsm:0.3", n_episodes=3, out_dir=tmp_path)
    by = {r["label"]: r for r in rows}
    assert by["none_0"]["mean_return"] >= 90.0  # the clean policy reaches the goal (the optimum is 93)
    assert by["gaussian_0.3"]["mean_return"] > 50
    assert by["pgd_0.3"]["mean_return"] < by["gaussian_0.3"]["mean_return"] - 100
    assert by["pgd_0.3"]["max_perturbation"] <= 0.3 + 1e-6
    with open(tmp_path / "adversarial.csv", newline="") as fh:
        table = list(csv.DictReader(fh))
    assert [r["attack"] for r in table] == ["none", "gaussian", "pgd", "fgsm"]
    assert {"eps", "mean_return", "std_return", "success_rate", "violations", "episodes"} <= set(table[0])
    assert (tmp_path / "adversarial.png").stat().st_size > 1000


def test_callback_logs_and_writes(tmp_path: Path) -> None:
    env = make_vec_env(GRID, n_envs=2, seed=0)
    model = PPO("MlpPolicy", env, n_steps=32, batch_size=64, seed=0, policy_kwargs={"net_arch": [16]})
    model.set_logger(configure(str(tmp_path / "log"), ["csv"]))
    eval_env = make_vec_env(GRID, n_envs=1, seed=1)
    cb = AdversarialEvalCallback(eval_env, "uniform:0.2 pgd:0.2", eval_freq=32, n_eval_episodes=1,
                                 path=tmp_path)
    model.learn(128, callback=cb)
    with open(tmp_path / "adversarial.csv", newline="") as fh:
        table = list(csv.DictReader(fh))
    assert [int(r["timesteps"]) for r in table[::3]] == [64, 128]  # evaluations at vec steps 32 and 64
    assert [r["attack"] for r in table[:3]] == ["none", "uniform", "pgd"]
    with open(tmp_path / "log" / "progress.csv", newline="") as fh:
        logged = list(csv.DictReader(fh))
    assert {"adversarial/pgd_0.2/mean_return", "adversarial/clean/mean_return"} <= set(logged[0])
    assert (tmp_path / "adversarial.png").exists()


def test_multi_agent_team_episodes() -> None:
    from sbagents.envs import treasure_hunt_v0
    from sbagents.multiagent import parameter_sharing as multiagent

    venv = multiagent.make_parameter_sharing_vec_env(treasure_hunt_v0.parallel_env, n_envs=2, seed=0)
    model = PPO("MlpPolicy", venv, n_steps=8, batch_size=48, seed=0, policy_kwargs={"net_arch": [16]})
    clean = evaluate_under_attack(model, venv, AttackSpec("none", 0.0), n_episodes=3, seed=0)
    attacked = evaluate_under_attack(model, venv, AttackSpec("pgd", 0.1), n_episodes=3, seed=0)
    for result in (clean, attacked):  # team episodes, counted once per env, not once per agent
        assert result["episodes"] == 3 and 1 <= result["mean_length"] <= 50
    assert 0 < attacked["max_perturbation"] <= 0.1 + 1e-6
