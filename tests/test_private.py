"""DP-SGD training (sbagents.private): the accountant against Opacus's, the sampling it assumes, the wiring into
SB3's actor-critics, and ``python -m sbagents.train --dp-*``."""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from cli_helpers import cli, summary
from opacus.accountants.rdp import RDPAccountant
from stable_baselines3 import A2C, DDPG, PPO, SAC, TD3
from stable_baselines3.common.env_util import make_vec_env

import sbagents  # noqa: F401 (registers the env ids)
from sbagents.private.accounting import (
    ORDERS,
    RolloutLedger,
    epsilon_of,
    noise_for_epsilon,
    round_rate_up,
)
from sbagents.private.callback import DPCallback
from sbagents.private.dp_sgd import make_private, planned_model_draws
from sbagents.private.on_policy import model_rollout_schedule
from sbagents.private.replay import PoissonReplayBuffer
from sbagents.private.rollout import PoissonRolloutBuffer
from sbagents.state_files import load_vecnormalize

torch.set_num_threads(1)
SMART = "sbagents/SmartHome-v0"
#: a fixed schedule {(q, k): draws}: a growing buffer, then a full one; DDPG-like (k = 2) and TD3-like (k = 1)
SCHEDULE = Counter({(0.25, 2): 100, (0.1, 2): 400, (0.02, 2): 3000, (0.02, 1): 1500})


def opacus_epsilon(schedule: Counter[tuple[float, int]], sigma: float, delta: float,
                   alphas: list[float] | None = None) -> float:
    """Opacus's own RDP accountant on the same draws (sigma / sqrt(k) per draw)."""
    accountant = RDPAccountant()
    accountant.history = [(sigma / math.sqrt(k), q, n) for (q, k), n in schedule.items()]
    return float(accountant.get_epsilon(delta, alphas=alphas))


@pytest.mark.parametrize("sigma", [0.8, 2.0, 4.0, 10.0])
def test_accountant_matches_opacus_for_a_fixed_schedule(sigma: float) -> None:
    ours = epsilon_of(SCHEDULE, sigma, 1e-5)
    assert ours == pytest.approx(opacus_epsilon(SCHEDULE, sigma, 1e-5, ORDERS), rel=1e-9)  # the same orders
    default = opacus_epsilon(SCHEDULE, sigma, 1e-5)  # Opacus's 151 orders (from 1.1): ours is never lower
    assert default <= ours
    if default <= 10:  # where orders below 2 do not matter: at most 3% looser
        assert ours <= 1.03 * default


def test_noise_calibration_hits_the_target_from_below() -> None:
    for target in (1.0, 3.0, 8.0):
        sigma = noise_for_epsilon(SCHEDULE, target, 1e-5)
        assert 0.99 * target <= epsilon_of(SCHEDULE, sigma, 1e-5) <= target
        assert epsilon_of(SCHEDULE, 0.97 * sigma, 1e-5) > target  # not much more noise than needed
    with pytest.raises(ValueError, match="epsilon must be > 0"):
        noise_for_epsilon(SCHEDULE, 0, 1e-5)


def test_noise_when_almost_nothing_is_drawn() -> None:
    """A budget below one gradient step (no draws: it was a ZeroDivisionError) takes the smallest noise tried; one
    tiny draw and a huge epsilon still calibrate from below."""
    assert 0 < noise_for_epsilon(Counter(), 1.0, 1e-5) < 1e-3
    sigma = noise_for_epsilon(Counter({(1e-4, 1): 1}), 1e4, 1e-5)
    assert 0.99e4 <= epsilon_of(Counter({(1e-4, 1): 1}), sigma, 1e-5) <= 1e4


def test_rates_round_up_on_a_fine_grid() -> None:
    rng = np.random.default_rng(0)
    for q in [*rng.uniform(1e-4, 1, 200), 1.0, 0.5, 0.01]:
        assert q <= round_rate_up(q) <= min(1.0, q * 1.024)


def test_poisson_batches_draw_each_transition_with_rate_q() -> None:
    env = make_vec_env(SMART, n_envs=2, seed=0)
    buffer = PoissonReplayBuffer(1000, env.observation_space, env.action_space, n_envs=2)
    for i in range(400):  # 800 transitions; obs[0] tags each with its index
        obs = np.full((2, 5), 0.0, np.float32)
        obs[:, 0] = [2 * i, 2 * i + 1]
        buffer.add(obs, obs, np.zeros((2, 2), np.float32), np.zeros(2), np.zeros(2), [{}, {}])
    np.random.seed(0)
    rates: list[float] = []
    buffer.on_draw = rates.append
    counts = np.zeros(800)
    sizes = []
    for _ in range(2000):
        batch = buffer.sample(40)
        tags = batch.observations[:, 0].numpy().astype(int)
        assert len(set(tags)) == len(tags)  # without replacement
        counts[tags] += 1
        sizes.append(len(tags))
    assert rates == [40 / 800] * 2000 and buffer.n_draws == 2000
    assert abs(np.mean(sizes) - 40) < 0.5 and np.std(sizes) == pytest.approx(math.sqrt(40 * 0.95), rel=0.1)
    assert np.abs(counts / 2000 - 0.05).max() < 0.025  # every transition at ~q (binomial, 2000 draws)


@pytest.mark.parametrize(("algo", "kwargs"), [
    (DDPG, {}),
    (TD3, {"train_freq": 4, "gradient_steps": 2}),
    (SAC, {"ent_coef": 0.1, "gradient_steps": -1, "train_freq": 2}),
])
def test_the_plan_is_the_draws_training_makes(algo: type, kwargs: dict[str, object]) -> None:
    """:func:`planned_draws` (used to calibrate the noise before training) predicts the ledger of a real run."""
    env = make_vec_env(SMART, n_envs=2, seed=0)
    model = algo("MlpPolicy", env, seed=0, learning_starts=64, batch_size=16, buffer_size=300,
                 policy_kwargs={"net_arch": [8]}, replay_buffer_class=PoissonReplayBuffer, **kwargs)
    dp = make_private(model, max_grad_norm=1.0, noise_multiplier=1.5)
    planned = planned_model_draws(model, 300)  # a small budget: the plumbing, not learning
    model.learn(300)
    assert dp.ledger.spent() == planned and sum(planned.values()) == dp.ledger.n_draws > 0
    assert dp.ledger.epsilon() == pytest.approx(epsilon_of(planned, 1.5, 1e-5))


def test_dp_steps_see_only_their_own_batch_and_clip_it() -> None:
    """Each noisy step's per-transition gradients are those of the current Poisson batch (the actor's pass through
    the critic leaves nothing behind for the next critic step), and noise 0 with a tiny clip barely moves weights."""
    env = make_vec_env(SMART, n_envs=1, seed=0)
    model = DDPG("MlpPolicy", env, seed=0, learning_starts=100, batch_size=32, policy_kwargs={"net_arch": [16]},
                 replay_buffer_class=PoissonReplayBuffer)
    dp = make_private(model, max_grad_norm=1e-6, noise_multiplier=0.0)
    buffer = model.replay_buffer
    assert isinstance(buffer, PoissonReplayBuffer)
    sizes: list[int] = []
    original = buffer._transitions

    def recording(*args: Any) -> Any:
        batch = original(*args)
        sizes.append(len(batch.observations))
        return batch

    buffer._transitions = recording  # type: ignore[method-assign,assignment]
    seen: list[tuple[str, int, float]] = []

    def recorder(name: str, ledger_hook: Callable[[Any], None]) -> Callable[[Any], None]:
        def hook(opt: Any) -> None:  # after clipping, before the noise: the clipped sum of this batch
            seen.append((name, int(opt.grad_samples[0].shape[0]), max(float(p.summed_grad.norm()) for p in opt.params)))
            ledger_hook(opt)
        return hook

    for name in ("critic", "actor"):
        optimizer = getattr(model, name).optimizer
        optimizer.step_hook = recorder(name, optimizer.step_hook)
    before = [p.detach().clone() for p in model.actor.parameters()]
    model.learn(160)
    assert len(sizes) == 60 and [s[0] for s in seen] == ["critic", "actor"] * 60
    assert [s[1] for s in seen] == [n for n in sizes for _ in (0, 1)]
    assert all(s[2] <= 1e-6 * s[1] * 1.0001 for s in seen)  # the sum of n clipped gradients
    moved = max(float((a.detach() - b).abs().max()) for a, b in zip(model.actor.parameters(), before, strict=True))
    assert moved < 0.1  # Adam's first steps move each weight by ~lr = 1e-3 per step at most
    assert dp.ledger.spent() == planned_model_draws(model, 160)


def test_what_cannot_be_made_private_is_refused() -> None:
    env = make_vec_env(SMART, n_envs=1, seed=0)
    plain = DDPG("MlpPolicy", env, seed=0)
    with pytest.raises(ValueError, match="replay_buffer_class=PoissonReplayBuffer"):
        make_private(plain, noise_multiplier=1.0)
    auto = SAC("MlpPolicy", env, seed=0, replay_buffer_class=PoissonReplayBuffer)
    with pytest.raises(ValueError, match="fixed ent_coef"):
        make_private(auto, noise_multiplier=1.0)
    fixed = SAC("MlpPolicy", env, seed=0, ent_coef=0.1, replay_buffer_class=PoissonReplayBuffer)
    with pytest.raises(ValueError, match="give noise_multiplier, or target_epsilon"):
        make_private(fixed)


def test_train_with_a_target_epsilon_writes_the_privacy_spent(tmp_path: Path) -> None:
    done = cli("train", "--algo", "ddpg", "--env", "SmartHome-v0", "-n", "800", "-f", str(tmp_path), "--seed", "0",
               "--eval-freq", "0", "--final-eval-episodes", "2", "--dp-epsilon", "8", "--dp-clip", "0.5",
               "-params", "learning_starts:400", "batch_size:64")
    assert done.returncode == 0, done.stderr
    assert "privacy: epsilon 7.9" in done.stdout or "privacy: epsilon 8.00" in done.stdout
    run = tmp_path / "ddpg" / "sbagents_SmartHome-v0_1"
    dp = summary(run)["dp"]
    assert 7.9 <= dp["epsilon"] <= 8 and dp["delta"] == 1e-5 and dp["max_grad_norm"] == 0.5
    assert dp["accountant"] == "rdp" and dp["unit"] == "transition"
    assert dp["draws"] == 50  # the entry's dp_overrides: a noisy step every train_freq 8 env steps after 400
    assert not dp["stopped_at_budget"]
    stats = load_vecnormalize(run / "vecnormalize.npz", make_vec_env(SMART, n_envs=1))
    space = stats.observation_space
    assert np.allclose(stats.obs_rms.mean, (space.low + space.high) / 2)  # type: ignore[union-attr,attr-defined]
    exported = cli("export", "--algo", "ddpg", "--env", "SmartHome-v0", "-f", str(tmp_path))
    assert exported.returncode == 0, exported.stderr
    report = json.loads((run / "export" / "policy.json").read_text())["report"]
    assert report["parity_fp32"] <= 1e-4


def test_train_with_a_given_noise_stops_before_the_budget(tmp_path: Path) -> None:
    done = cli("train", "--algo", "td3", "--env", "SmartHome-v0", "-n", "3000", "-f", str(tmp_path), "--seed", "0",
               "--eval-freq", "0", "--final-eval-episodes", "0", "--dp-noise", "3", "--dp-epsilon", "3.3",
               "-params", "learning_starts:300", "batch_size:32", "policy_kwargs:{net_arch: [16]}")
    assert done.returncode == 0, done.stderr
    data = summary(tmp_path / "td3" / "sbagents_SmartHome-v0_1")
    assert data["dp"]["stopped_at_budget"] and 3.0 < data["dp"]["epsilon"] <= 3.3
    assert 300 < data["n_timesteps"] < 3000 and "stopped at the budget" in done.stdout


@pytest.mark.parametrize(("args", "message"), [
    (["--algo", "dqn", "--env", "CartPole-v1", "--dp-epsilon", "8"],
     "DP training (--dp-*) is for ddpg, td3, sac, a2c, ppo"),
    (["--algo", "ppo", "--env", "treasure_hunt_v0", "--dp-noise", "1"],
     "DP training (--dp-*) trains single-agent envs, not team envs (treasure_hunt_v0)"),
    (["--algo", "ddpg", "--dp-epsilon", "0"], "--dp-epsilon must be a finite number > 0"),
    (["--algo", "ddpg", "--dp-epsilon", "-1"], "--dp-epsilon must be a finite number > 0"),
    (["--algo", "ddpg", "--dp-epsilon", "8", "--dp-delta", "0.001"], "--dp-delta 0.001 must be below 1 / 40,000"),
    (["--algo", "ddpg", "--dp-noise", "0"], "--dp-noise must be a finite number > 0"),
    (["--algo", "ddpg", "--dp-clip", "2"], "add --dp-epsilon E or --dp-noise SIGMA"),
    (["--algo", "sac", "--dp-epsilon", "8"], "needs a fixed ent_coef"),
    (["--algo", "ddpg", "--dp-noise", "1", "--dp-epsilon", "5", "-params", "train_freq:[1, episode]"],
     "--dp-epsilon plans the run's batches, which needs train_freq in steps"),
    (["--algo", "ppo", "--dp-epsilon", "8", "-params", "target_kl:0.02"], "DP training cannot use target_kl"),
    (["--algo", "ppo", "--dp-epsilon", "8", "-params", "normalize_advantage:true"],
     "DP training needs normalize_advantage: false"),
    (["--algo", "ppo", "--dp-epsilon", "8", "-params", "use_sde:true"], "DP training does not support use_sde"),
    (["--algo", "ppo", "--dp-epsilon", "8", "-n", "200000"], "--dp-delta 1e-05 must be below 1 / 200,000"),
    (["--algo", "ppo", "--dp-noise", "0.5", "--dp-epsilon", "4", "-n", "4096"],
     "--dp-noise 0.5 spends epsilon"),
    (["--algo", "ddpg", "-params", "dp_overrides:{batch_size: 64}"],
     "-params dp_overrides applies only to runs with --dp-* (here it would change nothing)"),
])
def test_bad_dp_input_is_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    done = cli("train", "--env", "SmartHome-v0", "-f", str(tmp_path), *args)
    assert done.returncode == 2 and message in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not any(tmp_path.iterdir())


# ---------------------------------------------------------------- on-policy: PPO and A2C

def test_rollout_ledger_matches_opacus_per_rollout_and_over_all_steps() -> None:
    """One transition is exposed to its own rollout's steps (parallel composition over disjoint rollouts): the
    ledger's epsilon is Opacus's RDPAccountant on one rollout's schedule; ``epsilon_all_steps`` on all of them."""
    q, steps, sigma, rollouts = 0.125, 80, 1.1, 5
    ledger = RolloutLedger(sigma, 1e-5)
    for _ in range(rollouts):
        ledger.on_rollout()
        for _ in range(steps):
            ledger.on_draw(q)
            ledger.on_step()
    grid = round_rate_up(q)  # the ledger rounds rates up (an upper bound): the same rate for Opacus
    one = Counter({(grid, 1): steps})
    assert ledger.epsilon() == pytest.approx(opacus_epsilon(one, sigma, 1e-5, ORDERS), rel=1e-9)
    assert ledger.epsilon_all_steps() == pytest.approx(
        opacus_epsilon(Counter({(grid, 1): steps * rollouts}), sigma, 1e-5, ORDERS), rel=1e-9)
    assert ledger.epsilon() < ledger.epsilon_all_steps() and ledger.n_rollouts == rollouts
    exact = opacus_epsilon(Counter({(q, 1): steps}), sigma, 1e-5)  # the exact rate, Opacus's default orders
    assert exact <= ledger.epsilon() <= 1.03 * exact
    ledger.on_rollout()  # a partial rollout (training stopped): the worst rollout still counts
    ledger.on_draw(q)
    ledger.on_step()
    assert ledger.epsilon() == pytest.approx(opacus_epsilon(one, sigma, 1e-5, ORDERS), rel=1e-9)


def _tagged_rollout(n_steps: int, n_envs: int, batch_size_hint: int = 0) -> PoissonRolloutBuffer:
    """A full rollout buffer whose observation[0] is each transition's index."""
    env = make_vec_env(SMART, n_envs=n_envs, seed=0)
    buffer = PoissonRolloutBuffer(n_steps, env.observation_space, env.action_space, n_envs=n_envs)
    for step in range(n_steps):
        obs = np.zeros((n_envs, 5), np.float32)
        obs[:, 0] = [step * n_envs + e for e in range(n_envs)]
        buffer.add(obs, np.zeros((n_envs, 2), np.float32), np.zeros(n_envs), np.zeros(n_envs),
                   torch.zeros(n_envs), torch.zeros(n_envs))
    buffer.compute_returns_and_advantage(torch.zeros(n_envs), np.zeros(n_envs))
    return buffer


def test_poisson_rollout_minibatches_have_rate_q_and_every_transition_is_eligible() -> None:
    buffer = _tagged_rollout(100, 4)  # N = 400 transitions
    events: list[object] = []
    buffer.on_draw, buffer.on_rollout = events.append, lambda: events.append("rollout")
    np.random.seed(0)
    counts, sizes, passes = np.zeros(400), [], 300
    for _ in range(passes):
        batches = list(buffer.get(64))
        assert len(batches) == 7  # ceil(400 / 64), as many as SB3's shuffled pass
        for batch in batches:
            tags = batch.observations[:, 0].numpy().astype(int)
            assert len(set(tags)) == len(tags)  # without replacement within a minibatch
            counts[tags] += 1
            sizes.append(len(tags))
    assert events == [64 / 400] * 7 * passes and buffer.n_draws == 7 * passes
    assert abs(np.mean(sizes) - 64) < 0.5 and np.std(sizes) == pytest.approx(math.sqrt(64 * (1 - 0.16)), rel=0.1)
    expected = 7 * passes * 0.16  # every transition joins each minibatch with probability q
    sd = math.sqrt(expected * (1 - 0.16))  # binomial: 400 transitions all within 5 standard deviations
    assert counts.min() > 0 and np.abs(counts - expected).max() < 5 * sd
    assert np.std(counts) == pytest.approx(sd, rel=0.15)
    assert [len(b.observations) for b in buffer.get(None)] == [400]  # A2C's full batch: q = 1
    buffer.reset()
    assert events[-2:] == [1.0, "rollout"]


def _ppo(**kwargs: Any) -> PPO:
    env = make_vec_env(SMART, n_envs=2, seed=0)
    settings: dict[str, Any] = {"n_steps": 64, "batch_size": 32, "n_epochs": 2, "normalize_advantage": False,
                                "policy_kwargs": {"net_arch": [16]}, "seed": 0,
                                "rollout_buffer_class": PoissonRolloutBuffer, **kwargs}
    return PPO("MlpPolicy", env, **settings)


def test_ppo_per_sample_gradients_are_those_of_each_sample_alone() -> None:
    """Opacus's per-sample gradients of a loss of values, log-probs and entropy (PPO's ingredients) match one
    backward pass per sample, for every parameter, the Gaussian policy's ``log_std`` included."""
    model = _ppo()
    make_private(model, noise_multiplier=1.0)
    policy = model.policy
    obs, actions = torch.randn(6, 5), torch.randn(6, 2)

    def loss_of(rows: slice) -> torch.Tensor:
        values, log_prob, entropy = policy.evaluate_actions(obs[rows], actions[rows])
        assert entropy is not None  # a Gaussian policy's entropy is analytic
        return (values.flatten() ** 2 - 0.7 * log_prob - 0.1 * entropy).mean()

    params: dict[str, Any] = dict(policy.named_parameters())  # Opacus adds grad_sample to each
    policy.optimizer.zero_grad()
    loss_of(slice(None)).backward()
    batched = {name: p.grad_sample.clone() for name, p in params.items()}
    assert "log_std" in batched
    for i in range(6):
        policy.optimizer.zero_grad()
        loss_of(slice(i, i + 1)).backward()
        for name, p in params.items():
            assert torch.allclose(batched[name][i], p.grad_sample[0], atol=1e-5), name


def test_ppo_updates_are_the_clipped_per_sample_sum_whatever_sb3_clips() -> None:
    """With noise 0, each update's gradient is the sum of the per-sample gradients, each clipped to C, over the
    expected batch size: bounded by n C / batch_size, and untouched by SB3's whole-batch ``max_grad_norm``."""
    model = _ppo(max_grad_norm=1e-9, n_epochs=1)
    dp = make_private(model, max_grad_norm=0.01, noise_multiplier=0.0)
    optimizer: Any = model.policy.optimizer
    checked: list[int] = []
    ledger_hook = optimizer.step_hook

    def hook(opt: Any) -> None:  # after clipping, noise (0 here) and scaling: p.grad is what the step uses
        norms = torch.stack([g.reshape(len(g), -1).norm(dim=1) for g in opt.grad_samples], dim=1).norm(dim=1)
        factors = (0.01 / (norms + 1e-6)).clamp(max=1.0)
        assert (norms * factors <= 0.01 * 1.0001).all()
        for p, g in zip(opt.params, opt.grad_samples, strict=True):
            assert torch.allclose(p.grad, torch.einsum("i,i...", factors, g) / 32, atol=1e-7)
        total = math.sqrt(sum(float(p.grad.norm()) ** 2 for p in opt.params))
        assert total <= len(norms) * 0.01 / 32 * 1.0001
        assert total > 1e-6  # not SB3's clip to 1e-9: the DP optimizer recomputes the gradient
        checked.append(len(norms))
        ledger_hook(opt)

    optimizer.step_hook = hook
    model.learn(256)
    assert len(checked) == dp.ledger.n_steps == 2 * 4 and abs(np.mean(checked) - 32) < 12


def test_ppo_and_a2c_ledgers_follow_the_plan() -> None:
    """The draws of a real run are the planned ones; epsilon is one rollout's, and a noise given with a budget it
    cannot keep for one rollout stops learn before the first update."""
    model = _ppo()
    dp = make_private(model, noise_multiplier=1.2)
    planned = planned_model_draws(model, 512)
    model.learn(512)
    assert dp.ledger.spent() == planned == Counter({(round_rate_up(0.25), 1): 4 * 2 * 4})
    assert dp.ledger.epsilon() == pytest.approx(epsilon_of(model_rollout_schedule(model), 1.2, 1e-5))
    assert dp.summary()["rollouts"] == 4 and dp.summary()["unit"] == "rollout sample"
    a2c = A2C("MlpPolicy", make_vec_env(SMART, n_envs=2, seed=0), n_steps=8, gae_lambda=0.0, seed=0,
              policy_kwargs={"net_arch": [16]}, rollout_buffer_class=PoissonRolloutBuffer)
    dp_a2c = make_private(a2c, target_epsilon=8, delta=1e-5, total_timesteps=160)
    a2c.learn(160)
    assert dp_a2c.ledger.spent() == Counter({(1.0, 1): 10}) and dp_a2c.summary()["unit"] == "transition"
    assert 7.9 <= dp_a2c.ledger.epsilon() <= 8  # one full-batch step per rollout, calibrated to it
    stopped = _ppo()
    dp_stopped = make_private(stopped, noise_multiplier=0.5)
    callback = DPCallback(dp_stopped, stop_at=1.0, total_timesteps=512)
    stopped.learn(512, callback=callback)
    assert callback.stopped_at_budget and dp_stopped.ledger.n_steps == 0


def test_what_cannot_be_made_private_on_policy_is_refused() -> None:
    with pytest.raises(ValueError, match="rollout_buffer_class=PoissonRolloutBuffer"):
        make_private(_ppo(rollout_buffer_class=None), noise_multiplier=1.0)
    with pytest.raises(ValueError, match="normalize_advantage=False"):
        make_private(_ppo(normalize_advantage=True), noise_multiplier=1.0)
    with pytest.raises(ValueError, match="target_kl"):
        make_private(_ppo(target_kl=0.01), noise_multiplier=1.0)


def test_train_ppo_with_a_target_epsilon_writes_the_privacy_spent(tmp_path: Path) -> None:
    done = cli("train", "--algo", "ppo", "--env", SMART, "-n", "2048", "-f", str(tmp_path), "--seed", "0",
               "--eval-freq", "0", "--final-eval-episodes", "2", "--dp-epsilon", "8", "-tb", str(tmp_path / "tb"),
               "-params", "n_epochs:4")
    assert done.returncode == 0, done.stderr
    assert "privacy: epsilon " in done.stdout and "per rollout sample" in done.stdout
    run = tmp_path / "ppo" / "sbagents_SmartHome-v0_1"
    dp = summary(run)["dp"]
    assert 7.9 <= dp["epsilon"] <= 8 and dp["composition"] == "per rollout (parallel)" and dp["rollouts"] == 1
    assert dp["draws"] == dp["noisy_steps"] == 4 * 8  # 4 epochs of 2048 / 256 minibatches
    assert dp["epsilon_all_steps"] == pytest.approx(dp["epsilon"], abs=1e-3)  # a single rollout
    assert "normalize_advantage: false" in (run / "sbagents_SmartHome-v0" / "config.yml").read_text()
    assert list((tmp_path / "tb").rglob("events.out.tfevents.*"))
    model = PPO.load(str(run / "sbagents_SmartHome-v0.zip"))  # plain SB3, no Opacus state
    assert set(model.policy.state_dict()) == set(PPO("MlpPolicy", make_vec_env(SMART, n_envs=1), policy_kwargs={
        "net_arch": [64, 64]}).policy.state_dict())
    exported = cli("export", "--algo", "ppo", "--env", SMART, "-f", str(tmp_path))
    assert exported.returncode == 0, exported.stderr
    report = json.loads((run / "export" / "policy.json").read_text())["report"]
    assert report["parity_fp32"] <= 1e-4
