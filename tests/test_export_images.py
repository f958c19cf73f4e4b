"""Export of image policies: the ONNX graph takes images as the env gives them (channels last, the transposition SB3
does for its CNNs inside the graph); an Atari run exports as its policy works inside AtariWrapper and the frame
stack (sidecar ``preprocessing``), and the torch-free server takes its 84x84x4 observations."""

from __future__ import annotations

import http.client
import json
import os
import re
import select
import subprocess
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import onnxruntime as ort
import pytest
import torch
from cli_helpers import cli, serve_command
from gymnasium import spaces
from stable_baselines3 import DQN, PPO
from stable_baselines3.common.base_class import BaseAlgorithm

from sbagents.core.run_dir import RunRef, load_run
from sbagents.deploy.onnx_export import export_onnx, taken_observation_space
from sbagents.deploy.serving import MAX_REQUEST_BYTES, DecisionLog, Policy, decide, request_limit

PONG = "PongNoFrameskip-v4"


class _Screens(gym.Env[np.ndarray, int]):
    """Random 84x84x4 uint8 screens, 6 actions: a channels-last image env."""

    def __init__(self) -> None:
        self.observation_space = spaces.Box(0, 255, (84, 84, 4), np.uint8)
        self.action_space = spaces.Discrete(6)  # type: ignore[assignment]

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        return self.observation_space.sample(), {}

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict]:
        return self.observation_space.sample(), 0.0, False, False, {}


def _blocky(n: int, seed: int = 0) -> np.ndarray:
    """``n`` images ``(84, 84, 4)`` uint8 of 6x6 random blocks per channel (pixel noise would give a CNN nearly the
    same features for every image)."""
    blocks = np.random.default_rng(seed).integers(0, 256, (n, 6, 6, 4), dtype=np.uint8)
    return np.repeat(np.repeat(blocks, 14, axis=1), 14, axis=2)


@pytest.mark.parametrize("algo", [PPO, DQN])
def test_channels_last_graph_acts_as_sb3(algo: type[BaseAlgorithm], tmp_path: Path) -> None:
    extra: dict[str, Any] = {"buffer_size": 100} if algo is DQN else {}
    model = algo("CnnPolicy", _Screens(), seed=0, device="cpu", **extra)
    assert model.observation_space.shape == (4, 84, 84)  # SB3 transposed the env's images for its CNN
    policy: Any = model.policy
    last = policy.action_net if isinstance(model, PPO) else policy.q_net.q_net[0]
    with torch.no_grad():  # a last layer that makes the greedy action depend on the image (SB3's init: one action)
        torch.manual_seed(0)
        last.weight.normal_(0.0, 1.0)
        last.bias.zero_()
    taken = taken_observation_space(model, _Screens().observation_space)
    assert taken.shape == (84, 84, 4)
    session = ort.InferenceSession(str(export_onnx(model, tmp_path / "p.onnx", obs_space=taken)))
    assert session.get_inputs()[0].shape[1:] == [84, 84, 4]
    obs = _blocky(64)
    sb3 = np.asarray(model.predict(obs, deterministic=True)[0])
    onnx = np.asarray(session.run(None, {"obs": obs.astype(np.float32)})[0])
    assert len(set(sb3.tolist())) > 1 and onnx.tolist() == sb3.tolist()
    with pytest.raises(TypeError, match=r"takes observations of shape \(4, 84, 84\), not \(84, 84, 3\)"):
        export_onnx(model, tmp_path / "q.onnx", obs_space=spaces.Box(0, 255, (84, 84, 3), np.uint8))


@pytest.fixture(scope="module")
def pong_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A few PPO updates on Pong (the plain ALE env: AtariWrapper + 4-frame stack)."""
    logs = tmp_path_factory.mktemp("pong")
    result = cli("train", "--algo", "ppo", "--env", PONG, "--vec-env", "dummy", "-f", str(logs), "-n", "128",
                 "--seed", "0", "--eval-freq", "0", "--final-eval-episodes", "0", "--verbose", "0",
                 "-params", "n_envs:2", "n_steps:64", "batch_size:64", "n_epochs:1")
    assert result.returncode == 0, result.stderr
    return logs


@pytest.fixture(scope="module")
def pong_export(pong_run: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """The Pong run exported with ``--int8``: its folder and the command's output."""
    out = tmp_path_factory.mktemp("pong-export")
    result = cli("export", "--algo", "ppo", "--env", PONG, "-f", str(pong_run), "--out", str(out), "--int8",
                 "--n-observations", "200")
    assert result.returncode == 0, result.stderr
    return out, result.stdout


def test_atari_run_exports_behind_its_preprocessing_and_serves(pong_run: Path, pong_export: tuple[Path, str]) -> None:
    out, stdout = pong_export
    assert "parity fp32: max abs action difference 0.00e+00 over 200 observations" in stdout
    assert "works inside AtariWrapper + 4-frame stack" in stdout
    meta = json.loads((out / "policy.json").read_text())
    assert meta["preprocessing"] == {"env_wrapper": [{"class": "stable_baselines3.common.atari_wrappers.AtariWrapper",
                                                      "kwargs": {}}], "frame_stack": 4}
    assert meta["report"]["preprocessing"] == meta["preprocessing"]
    assert meta["observation_space"]["shape"] == [84, 84, 4] and len(meta["obs_names"]) == 84 * 84 * 4

    policy = Policy(out / "policy.onnx")  # the torch-free server: one 84x84x4 stack per line, as JSON numbers
    assert policy.obs_shape == (84, 84, 4) and policy.max_request_bytes > MAX_REQUEST_BYTES
    model = load_run(RunRef("ppo", PONG, pong_run)).model
    obs = _blocky(4, seed=1)
    with DecisionLog(policy, None) as log:
        replies = [decide(policy, json.dumps(o.ravel().tolist()), log) for o in obs]
        too_long = decide(policy, "[" + "255.0, " * policy.max_request_bytes + "0]", log)
    assert all(ok for ok, _ in replies)
    assert [json.loads(r) for _, r in replies] == np.asarray(model.predict(obs, deterministic=True)[0]).tolist()
    assert not too_long[0] and f"more than {policy.max_request_bytes} bytes" in too_long[1]


def test_http_takes_a_frame_stack_body_and_refuses_a_longer_one(pong_run: Path, pong_export: tuple[Path, str]
                                                                ) -> None:
    """A 128 KB body (over the 64 KiB of small policies) is one Atari observation; past the policy's limit: 413."""
    proc = subprocess.Popen(serve_command("--model", str(pong_export[0] / "policy.onnx"), "--http", "127.0.0.1:0"),
                            stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    try:
        assert proc.stderr is not None
        ready, _, _ = select.select([proc.stderr], [], [], 60)
        found = re.search(r"http://127\.0\.0\.1:(\d+)/", proc.stderr.readline() if ready else "")
        assert found
        conn = http.client.HTTPConnection("127.0.0.1", int(found.group(1)), timeout=30)
        obs = _blocky(1, seed=2)
        body = json.dumps(obs.ravel().tolist())
        assert len(body) > MAX_REQUEST_BYTES
        conn.request("POST", "/", body=body, headers={"Content-Type": "application/json"})
        reply = conn.getresponse()
        model = load_run(RunRef("ppo", PONG, pong_run)).model
        assert (reply.status, json.loads(reply.read())) == (200, int(model.predict(obs, deterministic=True)[0][0]))
        conn.request("POST", "/", body=" " * (request_limit(84 * 84 * 4) + 1),
                     headers={"Content-Type": "application/json"})
        assert conn.getresponse().status == 413
    finally:
        proc.kill()
        proc.wait()
