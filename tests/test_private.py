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
from stable_baselines3 import DDPG, SAC, TD3
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

import sbagents  # noqa: F401 (registers the env ids)
from sbagents.private.accounting import (
    ORDERS,
    epsilon_of,
    noise_for_epsilon,
    round_rate_up,
)
from sbagents.private.dp_sgd import make_private, planned_model_draws
from sbagents.private.replay import PoissonReplayBuffer

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
    planned = planned_model_draws(model, 500)
    model.learn(500)
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
    assert dp["accountant"] == "rdp" and dp["unit"] == "transition" and dp["draws"] == 400
    assert not dp["stopped_at_budget"]
    stats = VecNormalize.load(str(run / "vecnormalize.pkl"), make_vec_env(SMART, n_envs=1))
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
    (["--algo", "ppo", "--dp-epsilon", "8"], "DP training (--dp-*) is for ddpg, td3, sac"),
    (["--algo", "ddpg", "--dp-epsilon", "0"], "--dp-epsilon must be a finite number > 0"),
    (["--algo", "ddpg", "--dp-epsilon", "-1"], "--dp-epsilon must be a finite number > 0"),
    (["--algo", "ddpg", "--dp-epsilon", "8", "--dp-delta", "0.001"], "--dp-delta 0.001 must be below 1 / 8,000"),
    (["--algo", "ddpg", "--dp-noise", "0"], "--dp-noise must be a finite number > 0"),
    (["--algo", "ddpg", "--dp-clip", "2"], "add --dp-epsilon E or --dp-noise SIGMA"),
    (["--algo", "sac", "--dp-epsilon", "8"], "needs a fixed ent_coef"),
    (["--algo", "ddpg", "--dp-noise", "1", "--dp-epsilon", "5", "-params", "train_freq:[1, episode]"],
     "--dp-epsilon plans the run's batches, which needs train_freq in steps"),
])
def test_bad_dp_input_is_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    done = cli("train", "--env", "SmartHome-v0", "-f", str(tmp_path), *args)
    assert done.returncode == 2 and message in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not any(tmp_path.iterdir())
