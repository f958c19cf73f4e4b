"""Robust training (sbagents.robust): SA regularizer (PGD inner max, eps schedule, scale units, SATD3 / SADDPG),
adversarial rollouts (AdvTD3 & co.), the ``--robust`` grammar and the CLI round trip."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import configure
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

import sbagents  # noqa: F401  (registers sbagents/SmartHome-v0)
from sbagents.callbacks.attacks import AttackSpec, ObservationAttacker, observation_scale
from sbagents.errors import UsageError
from sbagents.robust import SADDPG, SATD3, AdvSAC, AdvTD3, SAAdvDDPG, SARegularizer, ramped_eps
from sbagents.robust.options import parse_robust

th.set_num_threads(1)


def _actor(seed: int = 0) -> th.nn.Module:
    th.manual_seed(seed)
    return th.nn.Sequential(th.nn.Linear(4, 32), th.nn.Tanh(), th.nn.Linear(32, 2), th.nn.Tanh())


def test_pgd_beats_random_points_and_stays_in_ball() -> None:
    actor = _actor()
    obs = th.randn(64, 4)
    scale = th.tensor([1.0, 2.0, 0.5, 4.0])
    reg = SARegularizer(eps=0.3, pgd_steps=10, ramp_fraction=0.0, scale=scale, generator=th.Generator().manual_seed(0))
    xa = reg.perturb(actor, obs, 0.3)
    radius = 0.3 * scale
    assert ((xa - obs).abs() <= radius + 1e-6).all()
    assert ((xa - obs).abs() >= radius - 1e-5).float().mean() > 0.5  # PGD ends mostly on the ball's faces
    with th.no_grad():
        ref = actor(obs)
        pgd = (actor(xa) - ref).pow(2).sum(-1)
        points = [obs + (th.rand(obs.shape) * 2 - 1) * radius for _ in range(50)]
        randoms = th.stack([(actor(xr) - ref).pow(2).sum(-1) for xr in points])
    assert pgd.mean() > randoms.max(dim=0).values.mean()  # beats the best of 50 random points on average
    assert (pgd > randoms.mean(dim=0)).all()  # and a typical random point on every sample


def test_penalty_zero_eps_and_gradient() -> None:
    actor, obs = _actor(), th.randn(16, 4)
    assert SARegularizer(eps=0.0)(actor, obs).item() == 0.0
    reg = SARegularizer(eps=0.5, ramp_fraction=0.5)
    assert reg(actor, obs, progress_remaining=1.0).item() == 0.0  # start of training: eps ramped to 0
    penalty = reg(actor, obs, progress_remaining=0.0)
    assert penalty.item() > 0
    penalty.backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in actor.parameters())


def test_critic_term_is_the_worst_q_drop() -> None:
    """The critic-aware term is ``weight * mean(Q(s, pi(s)) - Q(s, pi(s~)))`` with s~ a PGD minimizer of the critic:
    positive, larger than at random points of the ball, differentiable w.r.t. the actor only through pi(s~)."""
    actor, obs = _actor(), th.randn(32, 4)

    def critic(x: th.Tensor, a: th.Tensor) -> th.Tensor:  # best action: tanh of the first two inputs
        return -(a - th.tanh(x[:, :2])).pow(2).sum(dim=-1, keepdim=True)

    reg = SARegularizer(eps=0.3, kappa=0.0, ramp_fraction=0.0, critic_weight=2.0,
                        generator=th.Generator().manual_seed(0))  # fmt: skip
    assert reg(actor, obs).item() == 0.0  # no critic given: no term
    penalty = reg(actor, obs, critic=critic)
    with th.no_grad():
        clean = critic(obs, actor(obs))
        randoms = [(clean - critic(obs, actor(obs + (th.rand(obs.shape) * 2 - 1) * 0.3))).mean() for _ in range(20)]
    assert penalty.item() > 2.0 * max(r.item() for r in randoms) > 0
    penalty.backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in actor.parameters())


def test_eps_schedule() -> None:
    reg = SARegularizer(eps=0.2, ramp_fraction=0.5)
    assert [reg.eps_at(p) for p in (1.0, 0.9, 0.75, 0.5, 0.2, 0.0)] == pytest.approx([0, 0.04, 0.1, 0.2, 0.2, 0.2])
    assert SARegularizer(eps=0.2, ramp_fraction=0.0).eps_at(1.0) == pytest.approx(0.2)
    with pytest.raises(ValueError):
        SARegularizer(eps=-1.0)
    assert ramped_eps(0.2, 0.25, 0.9) == pytest.approx(0.08) and ramped_eps(0.2, 0.0, 1.0) == 0.2


@pytest.mark.parametrize("normalize", [False, True])
def test_scale_matches_attacks(normalize: bool) -> None:
    venv = DummyVecEnv([lambda: gym.make("sbagents/SmartHome-v0")])
    if normalize:
        venv = VecNormalize(venv, norm_reward=False)
    model = SATD3("MlpPolicy", venv, policy_kwargs={"net_arch": [8]}, sa_eps=0.2)
    attacker = ObservationAttacker(model.policy, venv, AttackSpec("pgd", 0.2))
    scale = observation_scale(venv.observation_space, venv)
    np.testing.assert_allclose(scale, attacker.scale.cpu().numpy())
    np.testing.assert_allclose(model.sa_scale, attacker.scale.cpu().numpy())
    if normalize:
        np.testing.assert_array_equal(scale, np.ones(5, dtype=np.float32))
    else:
        np.testing.assert_allclose(scale, [11.0, 101.0, 23.0, 10.0, 100.0])
    np.testing.assert_allclose(observation_scale(venv.observation_space), [11.0, 101.0, 23.0, 10.0, 100.0])
    with pytest.raises(ValueError, match="Box"):
        observation_scale(gym.spaces.Discrete(3))


@pytest.mark.parametrize("cls", [SATD3, SADDPG])
def test_train_logs_penalty_and_round_trip(cls: type[SATD3], tmp_path) -> None:  # type: ignore[no-untyped-def]
    venv = VecNormalize(make_vec_env("Pendulum-v1", n_envs=1, seed=0), norm_reward=False)
    model = cls(
        "MlpPolicy",
        venv,
        learning_starts=50,
        batch_size=32,
        train_freq=1,
        policy_kwargs={"net_arch": [64, 64]},
        sa_eps=0.2,
        sa_ramp_fraction=0.5,
        sa_pgd_steps=3,
        seed=0,
    )
    model.set_logger(configure(str(tmp_path / "log"), ["csv"]))
    seen: list[dict[str, float]] = []
    record = model.logger.record

    def spy(key: str, value, exclude=None) -> None:  # type: ignore[no-untyped-def]
        if key.startswith("robust/"):
            seen.append({key: float(value)})
        record(key, value, exclude)

    model.logger.record = spy  # type: ignore[method-assign]
    before = [p.detach().clone() for p in model.actor.parameters()]
    model.learn(200)  # plumbing: a small budget
    penalties = [d["robust/sa_penalty"] for d in seen if "robust/sa_penalty" in d]
    eps = [d["robust/eps"] for d in seen if "robust/eps" in d]
    assert penalties and all(np.isfinite(penalties)) and max(penalties) > 0
    assert eps[0] < 0.2 and eps[-1] == pytest.approx(0.2)  # ramp reached by half of the budget
    assert any(not th.equal(a, b) for a, b in zip(before, model.actor.parameters(), strict=True))
    assert not model.actor._forward_pre_hooks and not model.actor.optimizer._optimizer_step_pre_hooks

    model.save(tmp_path / "model")
    loaded = cls.load(tmp_path / "model", env=venv)
    assert type(loaded) is cls and loaded.sa_eps == 0.2 and loaded.sa_pgd_steps == 3
    np.testing.assert_array_equal(loaded.sa_scale, np.ones(3, dtype=np.float32))
    obs = venv.normalize_obs(np.stack([venv.observation_space.sample() for _ in range(4)]))
    np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])
    loaded.learn(60, reset_num_timesteps=False)  # continues training with the regularizer rebuilt


def test_penalty_changes_actor_update() -> None:
    """The SA term reaches the actor's gradient: same seed, kappa 0 vs 10 give different actors."""
    actors = []
    for kappa in (0.0, 10.0):
        venv = make_vec_env("Pendulum-v1", n_envs=1, seed=0)
        model = SATD3(
            "MlpPolicy",
            venv,
            learning_starts=20,
            batch_size=16,
            policy_delay=1,
            seed=0,
            policy_kwargs={"net_arch": [16]},
            sa_eps=0.3,
            sa_kappa=kappa,
            sa_ramp_fraction=0.0,
        )
        model.learn(40)
        actors.append(th.cat([p.detach().flatten() for p in model.actor.parameters()]))
    assert not th.allclose(actors[0], actors[1])


def test_actor_step_uses_gradient_of_actor_loss_plus_penalty() -> None:
    """The hooked actor step sees exactly grad(-Q1(s, pi(s)).mean() + penalty(s)) on the actor-loss batch."""
    import copy

    venv = make_vec_env("Pendulum-v1", n_envs=1, seed=0)
    model = SATD3(
        "MlpPolicy", venv, learning_starts=40, batch_size=8, policy_delay=1, seed=0,
        policy_kwargs={"net_arch": [16]}, sa_eps=0.3, sa_kappa=5.0, sa_ramp_fraction=0.0,
    )  # fmt: skip
    model.learn(40)  # fills the buffer, no update yet
    seen: dict[str, object] = {}
    actor, opt = model.actor, model.actor.optimizer

    def first_input(_m: th.nn.Module, inputs: tuple[th.Tensor, ...]) -> None:
        seen.setdefault("obs", inputs[0].detach().clone())

    def before_step(*_: object) -> None:  # registered before SATD3's hook, so it runs first
        seen["actor"], seen["rng"] = copy.deepcopy(actor), th.get_rng_state()

    def after_step(*_: object) -> None:
        seen["grads"] = [p.grad.detach().clone() for p in actor.parameters()]  # type: ignore[union-attr]

    handles = [actor.register_forward_pre_hook(first_input), opt.register_step_pre_hook(before_step),
               opt.register_step_post_hook(after_step)]  # fmt: skip
    model.train(gradient_steps=1, batch_size=8)
    for h in handles:
        h.remove()
    ref_actor, obs = seen["actor"], seen["obs"]
    assert isinstance(ref_actor, th.nn.Module) and isinstance(obs, th.Tensor)
    ref_actor.zero_grad()
    loss = -model.critic.q1_forward(obs, ref_actor(obs)).mean()
    th.set_rng_state(seen["rng"])  # type: ignore[arg-type]
    (loss + model.sa_regularizer(ref_actor, obs, 0.0)).backward()
    for expected, got in zip((p.grad for p in ref_actor.parameters()), seen["grads"], strict=True):  # type: ignore[call-overload]
        th.testing.assert_close(got, expected)


def test_train_cli_robust_run_is_recorded_and_evaluates(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """``train --robust sa+adv:...`` trains an SAAdvTD3, records the spec in args.yml and the command, and the run
    loads for ``evaluate --attack`` like any TD3 run."""
    import json

    import yaml

    from sbagents.robust import SAAdvTD3
    from tests.cli_helpers import cli

    spec = "sa+adv:0.2,kappa=2,attack=critic,share=0.5"
    args = ["--algo", "td3", "--env", "sbagents/SmartHome-v0", "-n", "300", "-f", str(tmp_path), "--seed", "0",
            "--eval-freq", "0", "--final-eval-episodes", "1", "-params", "learning_starts:200", "--verbose", "0"]
    trained = cli("train", *args, "--robust", spec)
    assert trained.returncode == 0, trained.stderr
    run_dir = tmp_path / "td3" / "sbagents_SmartHome-v0_1"
    assert yaml.safe_load((run_dir / "sbagents_SmartHome-v0" / "args.yml").read_text())["robust"] == spec
    assert f"--robust {spec}" in (run_dir / "command.txt").read_text()
    model = SAAdvTD3.load(run_dir / "sbagents_SmartHome-v0.zip")
    assert (model.sa_eps, model.sa_kappa, model.adv_eps, model.adv_attack) == (0.2, 2.0, 0.2, "critic")
    assert model.sa_scale is not None and np.allclose(model.sa_scale, 1.0)
    evaluated = cli("evaluate", "--algo", "td3", "--env", "sbagents/SmartHome-v0", "-f", str(tmp_path), "-n", "2",
                    "--attack", "pgd:0.2", "--json")
    assert evaluated.returncode == 0, evaluated.stderr
    report = json.loads(evaluated.stdout.strip().splitlines()[-1])["adversarial"]
    assert [r["attack"] for r in report] == ["none", "pgd"]


# ---------------------------------------------------------------------------------------------- --robust grammar
@pytest.mark.parametrize(
    ("text", "algo", "cls", "kwargs"),
    [
        ("sa:0.2", "td3", SATD3, {"sa_eps": 0.2, "sa_kappa": 0.1, "sa_pgd_steps": 3}),  # the published recipe
        ("sa:0.3,kappa=2,steps=7,ramp=0", "ddpg", SADDPG,
         {"sa_eps": 0.3, "sa_kappa": 2.0, "sa_pgd_steps": 7, "sa_ramp_fraction": 0.0}),
        ("sa:0.2,qdrop=1.5", "td3", SATD3,
         {"sa_eps": 0.2, "sa_kappa": 0.1, "sa_pgd_steps": 3, "sa_critic_weight": 1.5}),
        ("adv:0.2", "td3", AdvTD3, {"adv_eps": 0.2}),
        ("adv:0.1,attack=critic,share=0.3", "sac", AdvSAC, {"adv_eps": 0.1, "adv_attack": "critic", "adv_share": 0.3}),
        ("sa+adv:0.3,kappa=0.5,attack=fgsm,ramp=0.25", "ddpg", SAAdvDDPG,
         {"sa_eps": 0.3, "sa_kappa": 0.5, "sa_pgd_steps": 3, "sa_ramp_fraction": 0.25, "adv_eps": 0.3,
          "adv_attack": "fgsm",
          "adv_ramp_fraction": 0.25}),
    ],
)
def test_robust_grammar(text: str, algo: str, cls: type, kwargs: dict[str, object]) -> None:
    spec = parse_robust(text, algo)
    assert spec.model_class(algo) is cls and spec.model_kwargs() == kwargs


@pytest.mark.parametrize(
    ("text", "algo", "message"),
    [
        ("pgd:0.2", None, "expected METHOD:EPS"),
        ("sa", None, "expected METHOD:EPS"),
        ("sa:-1", None, "EPS must be a finite number > 0"),
        ("adv:nan", None, "EPS must be a finite number > 0"),
        ("sa:0.2,share=0.5", None, "unknown setting 'share=0.5'; sa takes kappa=..., qdrop=..., ramp=..., steps=..."),
        ("adv:0.2,kappa=1", None, "unknown setting 'kappa=1'"),
        ("adv:0.2,share", None, "unknown setting 'share'"),
        ("adv:0.2,share=1.5", None, "share must be a number in [0, 1], got '1.5'"),
        ("adv:0.2,attack=foo", None, "attack must be one of pgd"),
        ("sa:0.2,steps=2.5", None, "steps must be an integer"),
        ("sa:0.2,kappa=-1", None, "kappa must be a number >= 0"),
        ("sa:0.2", "sac", "--robust sa trains ddpg, td3, not sac"),
        ("adv:0.2", "ppo", "--robust adv trains ddpg, td3, sac, not ppo"),
    ],
)
def test_robust_grammar_errors(text: str, algo: str | None, message: str) -> None:
    with pytest.raises(UsageError) as err:
        parse_robust(text, algo)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_train_cli_bad_robust_is_one_line() -> None:
    from tests.cli_helpers import cli

    done = cli("train", "--algo", "td3", "--env", "sbagents/SmartHome-v0", "--robust", "adv:0.2,share=2", "-n", "10")
    assert done.returncode == 2 and "share must be a number in [0, 1]" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and "Traceback" not in done.stderr


# ---------------------------------------------------------------------------------------------- adversarial rollouts
class _Recorder(DummyVecEnv):
    """A DummyVecEnv that remembers every observation it returns (the true ones)."""

    def __init__(self, fns) -> None:  # type: ignore[no-untyped-def]
        super().__init__(fns)
        self.seen: list[np.ndarray] = []

    def reset(self):  # type: ignore[no-untyped-def]
        obs = super().reset()
        self.seen.append(obs.copy())
        return obs

    def step_wait(self):  # type: ignore[no-untyped-def]
        obs, rewards, dones, infos = super().step_wait()
        self.seen.append(obs.copy())
        return obs, rewards, dones, infos


def test_adv_rollouts_act_on_attacked_observations_and_store_true_ones() -> None:
    """Every step after learning_starts (share 1) acts on an attacked observation inside the ramped ball; the replay
    buffer keeps the env's true observation and the action the policy took on the attacked one."""
    venv = _Recorder([lambda: gym.make("sbagents/SmartHome-v0")])
    steps, start, eps = 240, 40, 0.2
    model = AdvTD3("MlpPolicy", venv, learning_starts=start, train_freq=20, batch_size=16, seed=0,
                   policy_kwargs={"net_arch": [16]}, adv_eps=eps, adv_attack="pgd", adv_share=1.0,
                   adv_ramp_fraction=0.5)  # fmt: skip
    acted: list[tuple[np.ndarray, np.ndarray, float]] = []  # (policy input, action, scheduled eps)
    predict = model.predict

    def spy(obs, state=None, episode_start=None, deterministic=False):  # type: ignore[no-untyped-def]
        action, state = predict(obs, state, episode_start, deterministic)
        acted.append((obs.copy(), action.copy(), model.adv_eps_now()))
        return action, state

    model.predict = spy  # type: ignore[method-assign]
    model.learn(steps)
    assert len(acted) == steps - start
    scale = observation_scale(venv.observation_space)
    buffer = model.replay_buffer
    for k, (obs, action, eps_now) in enumerate(acted):
        t = start + k
        true = venv.seen[t]
        np.testing.assert_array_equal(buffer.observations[t], true)  # the buffer has the env's observation
        np.testing.assert_allclose(buffer.actions[t], model.policy.scale_action(action), atol=1e-6)
        rel = np.abs(obs - true) / scale
        assert rel.max() <= eps_now + 1e-5 and eps_now <= eps + 1e-9
        assert rel.max() > 0  # every step acted on a perturbed observation
    ramp = [e for _, _, e in acted]
    assert ramp == sorted(ramp) and ramp[-1] == pytest.approx(eps)
    assert ramp[0] == pytest.approx(eps * (start / steps) / 0.5)  # linear ramp over the first half
    assert model._adv_counts == [steps - start, steps - start]  # share 1: every step after learning_starts


def test_adv_share_and_plain_steps() -> None:
    """With share 0.5 about half the steps are attacked; the others act on the true observation."""
    model = AdvTD3("MlpPolicy", "Pendulum-v1", learning_starts=10, train_freq=50, batch_size=8, seed=1,
                   policy_kwargs={"net_arch": [8]}, adv_eps=0.1, adv_share=0.5, adv_ramp_fraction=0.0)  # fmt: skip
    model.learn(410)
    attacked, total = model._adv_counts
    assert total == model.num_timesteps - 10 and 0.4 < attacked / total < 0.6
    obs, mask = model.attacked_observations(np.zeros((64, 3), dtype=np.float32))
    assert obs.shape == (64, 3) and mask.shape == (64,)
    assert np.all(obs[~mask] == 0) and np.all(np.abs(obs[mask]).max(axis=1) > 0)


def test_adv_round_trip_and_bad_arguments(tmp_path) -> None:  # type: ignore[no-untyped-def]
    model = AdvTD3("MlpPolicy", "Pendulum-v1", learning_starts=10, batch_size=8, seed=0, adv_eps=0.3,
                   adv_attack="critic", adv_share=0.25, policy_kwargs={"net_arch": [8]})  # fmt: skip
    model.learn(30)
    model.save(tmp_path / "adv")
    loaded = AdvTD3.load(tmp_path / "adv", env=model.get_env())
    assert (loaded.adv_eps, loaded.adv_attack, loaded.adv_share) == (0.3, "critic", 0.25)
    loaded.learn(20, reset_num_timesteps=False)  # the attacker is rebuilt for the loaded policy
    assert loaded._adv_attacker is not None and loaded._adv_attacker.policy is loaded.policy
    with pytest.raises(ValueError, match="adv_attack"):
        AdvTD3("MlpPolicy", "Pendulum-v1", adv_attack="none")
    with pytest.raises(ValueError, match="adv_share"):
        AdvTD3("MlpPolicy", "Pendulum-v1", adv_share=2.0)


def test_a_spec_built_in_python_records_a_flag_value_that_parses_back() -> None:
    from sbagents.robust.options import RobustSpec

    spec = RobustSpec("adv", 0.2, (("attack", "critic"),))
    assert spec.flag_value() == "adv:0.2,attack=critic"
    assert parse_robust(spec.flag_value(), "td3").model_kwargs() == spec.model_kwargs()
    with pytest.raises(UsageError, match="--robust adv trains ddpg, td3, sac, not ppo"):
        spec.check_algo("ppo")
