"""PPO-Lagrangian / PID-Lagrangian: multiplier math, cost GAE, cost recording, save/load, and learning the safe path."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env

import sbagents  # noqa: F401  (registers sbagents/HazardGridWorld-v0)
from sbagents.constrained import (
    CostRolloutBuffer,
    CostRolloutBufferSamples,
    LagrangeMultiplier,
    PIDLagrangeMultiplier,
    PPOLagrangian,
)
from sbagents.constrained.lagrangian import MULTIPLIERS
from sbagents.constrained.options import CONSTRAINED_CLASSES, constrained_class, constraint_spec, own_keywords
from sbagents.core.run_dir import RunRef, config_path, load_run
from sbagents.errors import UsageError
from tests.cli_helpers import check_error, run_main, summary

torch.set_num_threads(1)


# -- multipliers -------------------------------------------------------------------------------------------------
def test_lagrange_multiplier_rises_above_the_limit_and_falls_to_zero_below() -> None:
    m = LagrangeMultiplier(cost_limit=1.0, lr=0.5)
    assert m.value == 0.0
    assert m.update(3.0) == pytest.approx(1.0)  # 0 + 0.5 * (3 - 1)
    assert m.update(2.0) == pytest.approx(1.5)
    assert m.update(0.0) == pytest.approx(1.0)  # below the limit: decreases
    assert m.update(0.0) == pytest.approx(0.5)
    assert m.update(0.0) == pytest.approx(0.0)
    assert m.update(0.0) == 0.0  # projected: never negative
    assert [h["multiplier"] for h in m.history] == pytest.approx([1.0, 1.5, 1.0, 0.5, 0.0, 0.0])
    assert [h["timesteps"] for h in m.history] == [1, 2, 3, 4, 5, 6]
    m.update(1.0, timesteps=1234)
    assert m.history[-1] == {"timesteps": 1234, "ep_cost": 1.0, "multiplier": 0.0}


def test_lagrange_multiplier_validates_and_clamps() -> None:
    with pytest.raises(ValueError, match="cost_limit"):
        LagrangeMultiplier(cost_limit=-1.0)
    with pytest.raises(ValueError, match="ep_cost"):
        LagrangeMultiplier(cost_limit=1.0).update(float("nan"))
    m = LagrangeMultiplier(cost_limit=0.0, lr=10.0, init=1.0, max_multiplier=5.0)
    assert m.update(100.0) == 5.0


def test_pid_integral_is_clamped_at_zero_and_has_no_windup() -> None:
    m = PIDLagrangeMultiplier(cost_limit=1.0, kp=0.0, ki=0.5, kd=0.0)
    for _ in range(10):  # long below the limit: the integral stays at 0, no negative windup
        assert m.update(0.0) == 0.0
    assert m.integral == 0.0
    assert m.update(3.0) == pytest.approx(1.0)  # reacts at once: 0.5 * (3 - 1)
    assert m.update(3.0) == pytest.approx(2.0)
    assert m.update(0.0) == pytest.approx(1.5)


def test_pid_with_only_ki_is_the_gradient_ascent_multiplier() -> None:
    costs = [3.0, 0.0, 2.5, 4.0, 0.0, 0.0, 0.0, 1.0]
    pid = PIDLagrangeMultiplier(cost_limit=1.0, kp=0.0, ki=0.2, kd=0.0)
    lag = LagrangeMultiplier(cost_limit=1.0, lr=0.2)
    assert [pid.update(c) for c in costs] == pytest.approx([lag.update(c) for c in costs])


def test_pid_proportional_and_derivative_terms() -> None:
    # P without EMA: lambda = max(0, kp * err + I); negative error lowers lambda below the integral
    m = PIDLagrangeMultiplier(cost_limit=1.0, kp=1.0, ki=0.1, kd=0.0, p_ema_alpha=0.0)
    assert m.update(3.0) == pytest.approx(2.0 + 0.2)
    assert m.update(0.9) == pytest.approx(-0.1 + 0.19)
    assert m.update(0.0) == 0.0  # -1 + 0.09 -> clamped at 0
    assert m.integral == pytest.approx(0.09)
    # D on the cost (not the error), delayed by d_delay updates, only when the cost rises
    d = PIDLagrangeMultiplier(cost_limit=10.0, kp=0.0, ki=0.0, kd=1.0, d_delay=2, d_ema_alpha=0.0)
    assert d.update(1.0) == pytest.approx(1.0)  # 1 - 0 (the initial 0)
    assert d.update(3.0) == pytest.approx(3.0)  # 3 - 0 (two updates ago: the initial 0)
    assert d.update(2.0) == pytest.approx(1.0)  # 2 - 1
    assert d.update(5.0) == pytest.approx(2.0)  # 5 - 3
    assert d.update(1.0) == 0.0  # 1 - 2 < 0: a falling cost does not push
    assert d.value >= 0.0


# -- cost GAE ----------------------------------------------------------------------------------------------------
def _buffer(n_steps: int, n_envs: int, **kwargs: Any) -> CostRolloutBuffer:
    return CostRolloutBuffer(
        n_steps, spaces.Box(-1, 1, (2,)), spaces.Discrete(2), device="cpu", n_envs=n_envs, **kwargs
    )


def test_cost_gae_matches_a_hand_computation() -> None:
    buf = _buffer(3, 1, gamma=0.99, gae_lambda=0.95, cost_gamma=0.5, cost_gae_lambda=0.8)
    buf.costs[:, 0] = [1.0, 0.0, 2.0]
    buf.cost_values[:, 0] = [0.4, 0.2, 1.0]
    buf.episode_starts[:, 0] = [1.0, 0.0, 1.0]  # an episode ends after step 1; a new one starts at step 2
    buf.compute_cost_returns_and_advantage(np.array([3.0]), dones=np.array([False]))
    g, lam = 0.5, 0.8
    d2 = 2.0 + g * 3.0 - 1.0  # bootstraps with the last value
    d1 = 0.0 + 0.0 - 0.2  # terminal: no bootstrap
    d0 = 1.0 + g * 0.2 - 0.4
    a2, a1 = d2, d1
    a0 = d0 + g * lam * a1
    np.testing.assert_allclose(buf.cost_advantages[:, 0], [a0, a1, a2], rtol=1e-6)
    np.testing.assert_allclose(buf.cost_returns[:, 0], [a0 + 0.4, a1 + 0.2, a2 + 1.0], rtol=1e-6)
    assert buf.cost_gamma == 0.5 and buf.gamma == 0.99
    assert _buffer(3, 1, gamma=0.9, gae_lambda=0.7).cost_gae_lambda == 0.7  # defaults follow the reward's


def test_buffer_samples_carry_the_cost_fields() -> None:
    buf = _buffer(4, 2)
    for _ in range(4):
        buf.add(np.zeros((2, 2)), np.zeros(2), np.zeros(2), np.zeros(2), torch.zeros(2), torch.zeros(2))
    buf.costs[:] = np.arange(8, dtype=np.float32).reshape(4, 2)
    buf.compute_cost_returns_and_advantage(np.zeros(2), np.ones(2))
    samples = list(buf.get(batch_size=8))
    assert len(samples) == 1 and isinstance(samples[0], CostRolloutBufferSamples)
    assert sorted(samples[0].cost_returns.tolist()) != [0.0] * 8
    assert samples[0].cost_advantages.shape == (8,)


# -- cost recording in rollouts --------------------------------------------------------------------------------
class _CostlyEnv(gym.Env[np.ndarray, int]):
    """Box obs, every step costs 1 (step 0 of an episode: 0.5); truncated after 3 steps."""

    observation_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
    action_space = spaces.Discrete(2)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(2, np.float32), {}

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        cost = 0.5 if self.t == 0 else 1.0
        self.t += 1
        obs = np.array([self.t / 3.0, -1.0], np.float32)
        return obs, 1.0, False, self.t >= 3, {"cost": cost}


def test_rollout_records_costs_and_bootstraps_truncation_with_the_cost_value() -> None:
    model = PPOLagrangian(
        "MlpPolicy",
        make_vec_env(_CostlyEnv, n_envs=1, seed=0),
        cost_limit=1.0,
        cost_gamma=0.9,
        multiplier_kwargs={"lr": 0.5},
        n_steps=6,
        batch_size=6,
        seed=0,
        device="cpu",
    )
    _, callback = model._setup_learn(6, None)
    assert model.collect_rollouts(model.env, callback, model.rollout_buffer, 6)  # type: ignore[arg-type]
    buf = model.rollout_buffer
    terminal = torch.tensor([[1.0, -1.0]])
    with torch.no_grad():
        v_term = float(model.predict_cost_values(terminal)[0])
    np.testing.assert_allclose(buf.costs[:, 0], [0.5, 1.0, 1.0 + 0.9 * v_term, 0.5, 1.0, 1.0 + 0.9 * v_term], rtol=1e-5)
    with torch.no_grad():
        expected_values = model.predict_cost_values(torch.as_tensor(buf.observations[:, 0])).numpy()
    np.testing.assert_allclose(buf.cost_values[:, 0], expected_values, rtol=1e-5)
    assert list(model.ep_cost_buffer) == [2.5, 2.5]
    assert model.multiplier.history == [{"timesteps": 6, "ep_cost": 2.5, "multiplier": pytest.approx(0.75)}]
    assert model.lagrange_multiplier == pytest.approx(0.75)


def test_combined_advantage_and_save_load_round_trip(tmp_path: Path) -> None:
    env = make_vec_env("sbagents/HazardGridWorld-v0", n_envs=2, seed=0)
    model = PPOLagrangian(
        "MlpPolicy",
        env,
        cost_limit=0.0,
        constraint="pid",
        multiplier_kwargs={"kp": 0.0, "ki": 1.0, "kd": 0.0},
        n_steps=64,
        batch_size=64,
        n_epochs=1,
        seed=0,
        device="cpu",
    )
    model.learn(256)
    assert len(model.multiplier.history) == 2 and model.lagrange_multiplier > 0.0
    buf = model.rollout_buffer  # flattened by the last update
    adv_r = (buf.reward_advantages - buf.reward_advantages.mean()) / (buf.reward_advantages.std() + 1e-8)
    adv_c = buf.cost_advantages - buf.cost_advantages.mean()
    lam = model.lagrange_multiplier
    np.testing.assert_allclose(buf.advantages, (adv_r - lam * adv_c) / (1 + lam), rtol=1e-4, atol=1e-5)

    model.save(tmp_path / "model.zip")
    loaded = PPOLagrangian.load(tmp_path / "model.zip", env=env, device="cpu")
    assert isinstance(loaded.multiplier, PIDLagrangeMultiplier)
    assert loaded.lagrange_multiplier == model.lagrange_multiplier
    assert loaded.multiplier.history == model.multiplier.history
    assert loaded.multiplier.integral == model.multiplier.integral
    assert (loaded.cost_limit, loaded.constraint, loaded.cost_gamma) == (0.0, "pid", model.gamma)
    obs = torch.as_tensor(np.arange(35).reshape(35, 1))
    with torch.no_grad():
        torch.testing.assert_close(loaded.predict_cost_values(obs), model.predict_cost_values(obs))
    for a, b in zip(
        loaded.cost_critic_optimizer.state_dict()["state"].values(),
        model.cost_critic_optimizer.state_dict()["state"].values(),
        strict=True,
    ):
        torch.testing.assert_close(a["exp_avg"], b["exp_avg"])
    loaded.learn(128, reset_num_timesteps=False)  # training continues after loading
    assert len(loaded.multiplier.history) == 3


def test_rejects_other_buffers_and_unknown_constraints() -> None:
    env = make_vec_env(_CostlyEnv, n_envs=1)
    with pytest.raises(ValueError, match="constraint"):
        PPOLagrangian("MlpPolicy", env, constraint="cpo")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="rollout_buffer_class"):
        PPOLagrangian("MlpPolicy", env, rollout_buffer_class=object)


# -- learning ----------------------------------------------------------------------------------------------------
def _greedy_episode(model: PPO) -> tuple[float, float]:
    env = gym.make("sbagents/HazardGridWorld-v0")
    obs, _ = env.reset(seed=0)
    ret = cost = 0.0
    done = False
    while not done:
        action, _ = model.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, info = env.step(int(action))
        ret, cost, done = ret + float(reward), cost + info["cost"], terminated or truncated
    return ret, cost


HAZARD_PPO: dict[str, Any] = {"n_steps": 64, "batch_size": 128, "n_epochs": 4, "ent_coef": 0.05, "learning_rate": 1e-3}


def _hazard_env() -> Any:
    return make_vec_env("sbagents/HazardGridWorld-v0", n_envs=8, seed=0)


PID_GAINS = {"kp": 0.1, "ki": 0.1, "kd": 0.0}  # the shipped entry's (zoo_configs/ppo.yml)


@pytest.mark.slow  # learning: the entry's 50k steps (~30 s here)
def test_pid_lagrangian_learns_the_safe_path() -> None:
    """HazardGridWorld: the short path (return 95) crosses a hazard (cost 1), the safe one returns 87.

    Measured with these hyperparameters and gains through the CLI (greedy return / cost at 50k): 87 / 0 on seeds
    0-4; with kp 0.5, ki 0.1, kd 0.1, d_delay 5 seed 2 stayed left of the hazards (-50 / 0). Seed 0 is pinned.
    """
    model = PPOLagrangian("MlpPolicy", _hazard_env(), cost_limit=0.1, constraint="pid", multiplier_kwargs=PID_GAINS,
                          seed=0, device="cpu", **HAZARD_PPO)
    model.learn(50_000)
    ret, cost = _greedy_episode(model)
    assert cost <= 0.1 and ret >= 0.9 * 87
    assert model.lagrange_multiplier > 0.0
    assert np.mean(list(model.ep_cost_buffer)[-20:]) <= 0.5  # the stochastic policy is mostly safe too


def test_train_cli_constraint_records_history_and_evaluates(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """``train --constraint lagrangian --cost-limit X`` trains PPO-Lagrangian without stopping at the limit, writes
    the multiplier's history into safety.json and the final state into summary.json; ``evaluate`` loads the run and
    reports its mean episode cost."""
    import json

    from tests.cli_helpers import cli

    trained = cli("train", "--algo", "ppo", "--env", "sbagents/HazardGridWorld-v0", "-n", "1024", "-f", str(tmp_path),
                  "--seed", "0", "--constraint", "pid", "--cost-limit", "0.1", "--eval-freq", "0",
                  "--final-eval-episodes", "2", "-params", "n_envs:4", "n_steps:64", "batch_size:64")
    assert trained.returncode == 0, trained.stderr
    line = next(x for x in trained.stdout.splitlines() if x.startswith("constraint (pid): cost limit 0.1 "))
    run_dir = tmp_path / "ppo" / "sbagents_HazardGridWorld-v0_1"
    safety = json.loads((run_dir / "safety.json").read_text())
    history = safety["constraint"]["history"]
    assert safety["cost_limit"] is None and not safety["stopped"]  # counted, never a stopping rule here
    assert [h["timesteps"] for h in history] == sorted(h["timesteps"] for h in history) and len(history) >= 2
    summary = json.loads((run_dir / "summary.json").read_text())
    item = summary["constraint"]
    assert item["method"] == "pid" and item["multiplier"] == history[-1]["multiplier"]
    recent = [h["ep_cost"] for h in history[-10:]]  # whether the limit held: in recent training episodes ...
    assert item["train_ep_cost"] == pytest.approx(sum(recent) / len(recent))
    assert item["held_in_training"] == (item["train_ep_cost"] <= 0.1)
    assert item["eval_ep_cost"] == summary["eval"]["mean_cost"]  # ... and in the final evaluation
    assert item["held_in_evaluation"] == (summary["eval"]["mean_cost"] <= 0.1)
    verdicts = ["held" if item[k] else "missed" for k in ("held_in_training", "held_in_evaluation")]
    assert line.startswith(f"constraint (pid): cost limit 0.1 {verdicts[0]} in training (recent episodes' mean cost "
                           f"{item['train_ep_cost']:.3g}); {verdicts[1]} in the final evaluation (mean episode cost "
                           f"{item['eval_ep_cost']:.3g}); multiplier")
    evaluated = cli("evaluate", "--algo", "ppo", "--env", "sbagents/HazardGridWorld-v0", "-f", str(tmp_path), "-n",
                    "2", "--json")
    assert evaluated.returncode == 0, evaluated.stderr
    assert "mean_cost" in json.loads(evaluated.stdout.strip().splitlines()[-1])


# -- the CLI: constraint_kwargs, misuse, the algorithm -> constrained class table --------------------------------
HAZARD = "sbagents/HazardGridWorld-v0"


def _train(folder: Path, *args: str) -> int:
    """``python -m sbagents.train --algo ppo --env HazardGridWorld ... args`` in this process (no evaluations)."""
    return run_main("train", "--algo", "ppo", "--env", HAZARD, "-f", str(folder), "--seed", "0", "--verbose", "0",
                    "--eval-freq", "0", "--final-eval-episodes", "0", *args)


@pytest.mark.parametrize(
    ("method", "params", "expected"),
    [
        ("lagrangian", [], {"lr": 0.1}),  # the shipped entry's multiplier_kwargs for each method
        ("pid", [], {"kp": 0.1, "ki": 0.1, "kd": 0.0}),
        ("lagrangian", ["-params", "constraint_kwargs:{multiplier_kwargs: {lr: 0.3}, cost_vf_learning_rate: 0.002}"],
         {"lr": 0.3}),
    ],
)
def test_constraint_kwargs_reach_the_multiplier_and_the_run_record(
    tmp_path: Path, method: str, params: list[str], expected: dict[str, float]
) -> None:
    import yaml

    assert _train(tmp_path, "-n", "512", "--constraint", method, "--cost-limit", "0.1", *params) == 0
    loaded = load_run(RunRef("ppo", HAZARD, tmp_path))
    model = loaded.model
    assert isinstance(model, PPOLagrangian) and type(model.multiplier) is MULTIPLIERS[method]
    assert {k: getattr(model.multiplier, k) for k in expected} == expected
    args = yaml.safe_load(config_path(loaded.run_dir, HAZARD).with_name("args.yml").read_text())
    assert (args["constraint"], args["cost_limit"]) == (method, 0.1)
    assert args["constraint_kwargs"]["multiplier_kwargs"] == expected  # this method's settings: the run repeats
    if params:
        assert model.cost_vf_learning_rate == 0.002
        assert model.cost_critic_optimizer.param_groups[0]["lr"] == 0.002


def test_plain_run_leaves_the_entrys_constraint_kwargs_unused(tmp_path: Path) -> None:
    assert _train(tmp_path, "-n", "512") == 0
    assert type(load_run(RunRef("ppo", HAZARD, tmp_path)).model) is PPO


LAG, PID = ["--constraint", "lagrangian", "--cost-limit", "0.1"], ["--constraint", "pid", "--cost-limit", "0.1"]
CONSTRAINT_MISUSE = [
    (["-params", "constraint_kwargs:{multiplier_kwargs: {lr: 0.2}}"],
     "-params constraint_kwargs configures --constraint runs; add --constraint lagrangian|pid --cost-limit X"),
    ([*LAG, "-params", "constraint_kwargs:{multiplier_kwargs: {kp: 1}}"],
     "constraint_kwargs: multiplier_kwargs kp do not apply to --constraint lagrangian"),
    ([*PID, "-params", "constraint_kwargs:{multiplier_kwargs: {pid: {lr: 1}}}"],
     "multiplier_kwargs lr do not apply to --constraint pid"),
    ([*LAG, "-params", "constraint_kwargs:{cost_gama: 0.9}"],
     "unknown constraint_kwargs key(s) cost_gama for PPOLagrangian"),
    ([*LAG, "-params", "constraint_kwargs:{multiplier_kwargs: {lr: -1}}"],
     "multiplier_kwargs of --constraint lagrangian: lr must be a finite number >= 0.0, got -1.0"),
    ([*LAG, "-params", "constraint_kwargs:[1]"],
     "constraint_kwargs must be a mapping"),
]


@pytest.mark.parametrize(("args", "expected"), CONSTRAINT_MISUSE, ids=[" ".join(a[-2:]) for a, _ in CONSTRAINT_MISUSE])
def test_constraint_kwargs_misuse_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], expected: str
) -> None:
    check_error(_train(tmp_path / "logs", *args), capsys.readouterr().err, expected)
    assert not (tmp_path / "logs").exists()


def test_constraint_kwargs_of_an_algo_without_a_constrained_class_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    conf = tmp_path / "dqn.yml"
    conf.write_text("sbagents/GridWorld-v0: {n_timesteps: 100, constraint_kwargs: {multiplier_kwargs: {lr: 0.1}}}\n")
    code = run_main("train", "--algo", "dqn", "-conf", str(conf), "-f", str(tmp_path / "logs"), "--verbose", "0")
    check_error(code, capsys.readouterr().err, "constraint_kwargs applies to ppo, sac (with --constraint), not dqn")


def test_constrained_classes_are_a_table_resolved_lazily(monkeypatch: pytest.MonkeyPatch) -> None:
    import sbagents.constrained as package

    assert CONSTRAINED_CLASSES == {"ppo": "PPOLagrangian", "sac": "SACLagrangian"}
    assert constrained_class("ppo") is PPOLagrangian
    assert own_keywords(PPOLagrangian, PPO) == ["cost_gae_lambda", "cost_gamma", "cost_vf_learning_rate",
                                                "multiplier_kwargs"]
    with pytest.raises(UsageError, match="--constraint trains ppo, sac, not a2c"):
        constrained_class("a2c")
    monkeypatch.delattr(package, "SACLagrangian", raising=False)  # the table names it whether or not it exists
    with pytest.raises(UsageError, match="needs sbagents.constrained.SACLagrangian, which this install lacks"):
        constrained_class("sac")
    monkeypatch.setitem(CONSTRAINED_CLASSES, "a2c", "PPOLagrangian")  # a new algorithm is one entry
    assert constrained_class("a2c") is PPOLagrangian
    spec = constraint_spec("pid", "ppo", 0.5, {"multiplier_kwargs": {"lagrangian": {"lr": 0.1}}, "cost_gamma": 0.9})
    assert spec.model_kwargs() == {"constraint": "pid", "cost_limit": 0.5, "multiplier_kwargs": {}, "cost_gamma": 0.9}


def _multiplier(folder: Path) -> LagrangeMultiplier:
    """The multiplier of the latest run in ``folder``, loaded as ``evaluate`` loads it."""
    model = load_run(RunRef("ppo", HAZARD, folder)).model
    assert isinstance(model, PPOLagrangian)
    return model.multiplier


def test_trained_agent_continues_its_multiplier_under_the_new_cost_limit(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``-i`` with ``--constraint``: the saved multiplier (and its history) goes on under the new ``--cost-limit``;
    another method, or a model trained without a constraint, is refused in one line."""
    assert _train(tmp_path / "lag", "-n", "512", *LAG) == 0
    assert _train(tmp_path / "plain", "-n", "512") == 0
    zips = {k: next((tmp_path / k).glob("ppo/*_1/*.zip")) for k in ("lag", "plain")}
    first = _multiplier(tmp_path / "lag")
    assert _train(tmp_path / "lag", "-n", "512", "--constraint", "lagrangian", "--cost-limit", "2", "-i",
                  str(zips["lag"])) == 0
    multiplier = _multiplier(tmp_path / "lag")
    assert multiplier.cost_limit == 2.0 and multiplier.history[0] == first.history[0]
    step = multiplier.history[1]
    assert step["multiplier"] == pytest.approx(max(0.0, first.value + 0.1 * (step["ep_cost"] - 2.0)))
    capsys.readouterr()
    check_error(_train(tmp_path / "x", *PID, "-i", str(zips["lag"])), capsys.readouterr().err,
                "-i/--trained-agent was trained with --constraint lagrangian: continue it with the same method")
    check_error(_train(tmp_path / "x", *PID, "-i", str(zips["plain"])), capsys.readouterr().err,
                "holds no PPOLagrangian model: --constraint continues a --constraint run's model")
    assert not list((tmp_path / "x").glob("ppo/*"))


@pytest.mark.slow  # learning: 20k + 50k steps (~45 s here)
def test_train_cli_plain_ppo_takes_the_hazard_path_lagrangian_the_safe_one(tmp_path: Path) -> None:
    """The shipped entry through ``train``: reward-only PPO takes the short path through a hazard (return 95, cost
    1; 20k steps), ``--constraint lagrangian --cost-limit 0.1`` the safe one (return 87, cost 0; the entry's 50k).

    Measured through the CLI at the entry's 50k: plain 95 / 1 and lagrangian 87 / 0 on seeds 0-4; plain PPO is on
    the hazard path by 20k (seeds 0-3 through the API). Seed 0 is pinned.
    """
    runs = {"plain": ["-n", "20000"], "lagrangian": LAG}
    for name, args in runs.items():
        assert _train(tmp_path / name, "--final-eval-episodes", "1", *args) == 0  # greedy, deterministic env
    plain, lagrangian = (summary(next((tmp_path / k).glob("ppo/*_1")))["eval"] for k in runs)
    assert plain["mean_cost"] >= 1.0 and plain["mean_return"] >= 0.95 * 95  # the hazard path: above the safe 87
    assert lagrangian["mean_cost"] <= 0.1 and lagrangian["mean_return"] >= 0.9 * 87
