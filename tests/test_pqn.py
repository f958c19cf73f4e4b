"""PQN (``--algo pqn``, :mod:`sbagents.algos.pqn`): its Q(lambda) returns against a hand computation, its networks
(LayerNorm after every hidden layer; the Nature CNN's shapes), learning CartPole, and the CLI's train, evaluate
(rebuilt from plain data) and ONNX export on a tiny budget; the channels-last CNN."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from cli_helpers import run_main
from gymnasium import spaces
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from torch import nn

from sbagents.algos.pqn import PQN, LayerNormNatureCNN, PQNCnnPolicy, QLambdaRolloutBuffer

GAMMA, LAMBDA = 0.9, 0.5


def test_q_lambda_returns_are_pengs_returns_cut_at_episode_ends() -> None:
    """One env, 4 steps: an episode ends after step 1 (step 2 starts a new one); the last step bootstraps from the
    value after the rollout."""
    buffer = QLambdaRolloutBuffer(4, spaces.Box(-1, 1, (2,)), spaces.Discrete(2), "cpu", n_envs=1)
    rewards, values, starts = [1.0, 2.0, 3.0, 4.0], [10.0, 20.0, 30.0, 40.0], [1.0, 0.0, 1.0, 0.0]
    for r, v, s in zip(rewards, values, starts, strict=True):
        buffer.add(np.zeros((1, 2)), np.zeros(1), np.array([r]), np.array([s]), torch.tensor([v]))
    buffer.compute_returns(torch.tensor([50.0]), np.array([False]), GAMMA, LAMBDA)
    g3 = 4 + GAMMA * 50
    g2 = 3 + GAMMA * (LAMBDA * g3 + (1 - LAMBDA) * 40)
    g1 = 2.0  # the next observation starts another episode: no bootstrap
    g0 = 1 + GAMMA * (LAMBDA * g1 + (1 - LAMBDA) * 20)
    assert buffer.returns[:, 0] == pytest.approx([g0, g1, g2, g3])
    buffer.compute_returns(torch.tensor([50.0]), np.array([True]), GAMMA, 0.0)  # one-step Q-learning, ended
    assert buffer.returns[:, 0] == pytest.approx([1 + GAMMA * 20, 2, 3 + GAMMA * 40, 4])


def test_the_networks_normalize_every_hidden_layer() -> None:
    env = make_vec_env("CartPole-v1", n_envs=2, seed=0)
    model = PQN("MlpPolicy", env, seed=0)
    layers = list(model.policy.q_net)
    assert [type(x) for x in layers] == [nn.Linear, nn.LayerNorm, nn.ReLU, nn.Linear, nn.LayerNorm, nn.ReLU, nn.Linear]
    assert [x.out_features for x in layers if isinstance(x, nn.Linear)] == [120, 84, 2]  # CleanRL's pqn.py
    images = spaces.Box(0, 255, (4, 84, 84), np.uint8)
    policy = PQNCnnPolicy(images, spaces.Discrete(6), lambda _: 2.5e-4)
    cnn = policy.features_extractor
    assert isinstance(cnn, LayerNormNatureCNN) and isinstance(policy.optimizer, torch.optim.RAdam)
    norms = [tuple(x.normalized_shape) for x in [*cnn.cnn, *cnn.linear] if isinstance(x, nn.LayerNorm)]
    assert norms == [(32, 20, 20), (64, 9, 9), (64, 7, 7), (512,)]  # the Nature CNN's shapes on 84x84
    obs = torch.as_tensor(np.stack([images.sample() for _ in range(3)]))
    assert policy.q_values(obs).shape == (3, 6) and policy.predict(obs.numpy())[0].shape == (3,)


def test_pqn_learns_cartpole() -> None:
    torch.set_num_threads(1)
    env = make_vec_env("CartPole-v1", n_envs=16, seed=0)
    model = PQN("MlpPolicy", env, n_steps=32, batch_size=128, n_epochs=4, learning_rate=1e-3,
                exploration_fraction=0.2, exploration_final_eps=0.01, seed=0)
    model.learn(64_000)
    mean, _ = evaluate_policy(model, make_vec_env("CartPole-v1", n_envs=1, seed=1), n_eval_episodes=10)
    assert mean >= 150  # random play: about 22
    assert model.exploration_rate == pytest.approx(0.01)


def test_train_evaluate_and_export_through_the_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    logs = tmp_path / "logs"
    assert run_main("train", "--algo", "pqn", "--env", "CartPole-v1", "-n", "1024", "-params", "n_envs:4",
                    "n_steps:32", "batch_size:64", "-f", str(logs), "--eval-freq", "-1", "--final-eval-episodes", "2",
                    "--verbose", "0") == 0
    assert run_main("evaluate", "--algo", "pqn", "--env", "CartPole-v1", "-f", str(logs), "-n", "2") == 0
    capsys.readouterr()
    assert run_main("export", "--algo", "pqn", "--env", "CartPole-v1", "-f", str(logs)) == 0
    out = capsys.readouterr().out
    assert "parity fp32: max abs action difference 0.00e+00" in out
    (model,) = logs.rglob("CartPole-v1.zip")
    loaded = PQN.load(model)
    assert loaded.q_lambda == 0.65 and loaded.n_epochs == 4 and loaded.num_timesteps == 1024  # pqn.yml's entry


def test_pqn_learns_gridworld_on_the_batched_vec_env(tmp_path: Path) -> None:
    """The ``default`` entry on the book's GridWorld, stepped by the batched (numpy) vec env: the shortest path."""
    import json

    code = run_main("train", "--algo", "pqn", "--env", "sbagents/GridWorld-v0", "--vec-env", "batched", "-n", "20000",
                    "-f", str(tmp_path), "--seed", "0", "--eval-freq", "-1", "--verbose", "0")
    assert code == 0
    run_dir = tmp_path / "pqn" / "sbagents_GridWorld-v0_1"
    assert "vec_env: batched" in (run_dir / "sbagents_GridWorld-v0" / "args.yml").read_text()
    assert json.loads((run_dir / "summary.json").read_text())["eval"]["mean_return"] == 93.0


def test_channels_last_cnn_gives_the_same_q_values_and_rebuilds_from_plain_data(tmp_path: Path) -> None:
    """``features_extractor_kwargs: {channels_last: true}`` changes the memory layout, not the function, and a saved
    model keeps it when rebuilt by the safe loader."""
    from sbagents.atomic import save_model
    from sbagents.safe_load import load_model

    images = spaces.Box(0, 255, (4, 84, 84), np.uint8)
    plain = PQNCnnPolicy(images, spaces.Discrete(6), lambda _: 2.5e-4)
    fast = PQNCnnPolicy(images, spaces.Discrete(6), lambda _: 2.5e-4,
                        features_extractor_kwargs={"channels_last": True})
    fast.load_state_dict(plain.state_dict())
    conv = fast.features_extractor.cnn[0]
    assert conv.weight.is_contiguous(memory_format=torch.channels_last) and not conv.weight.is_contiguous()
    obs = torch.as_tensor(np.stack([images.sample() for _ in range(5)]))
    with torch.no_grad():
        assert torch.allclose(fast.q_values(obs), plain.q_values(obs), atol=1e-5)

    class Frames(gym.Env):  # type: ignore[type-arg]
        observation_space, action_space = images, spaces.Discrete(6)

        def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:  # type: ignore[type-arg]
            super().reset(seed=seed)
            return images.sample(), {}

        def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict]:  # type: ignore[type-arg]
            return images.sample(), 0.0, False, False, {}

    model = PQN("CnnPolicy", make_vec_env(Frames, n_envs=2), n_steps=4, batch_size=8, seed=0,
                policy_kwargs={"features_extractor_kwargs": {"channels_last": True}})
    model.learn(16)
    loaded = load_model(PQN, save_model(model, tmp_path / "pqn.zip"), env=make_vec_env(Frames, n_envs=1))
    assert loaded.policy.features_extractor.channels_last
    with torch.no_grad():
        assert torch.equal(loaded.policy.q_values(obs), model.policy.q_values(obs))
