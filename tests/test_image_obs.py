"""Pixel observations of PettingZoo envs: the :mod:`sbagents.multiagent.preprocessing` wrappers (spaces, values equal
to OpenCV on the raw frames, the PettingZoo API), the shipped ``cooperative_pong_v6`` entry (CnnPolicy on 4 stacked
84x84 grayscale frames) through the train and evaluate CLIs, and one-line errors for layouts images cannot take.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from cli_helpers import cli, last_json, summary
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.butterfly import cooperative_pong_v6
from pettingzoo.test import parallel_api_test
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecFrameStack

from sbagents.cli_common import run
from sbagents.core.env_names import resolve_env
from sbagents.core.experiment import build_experiment
from sbagents.core.options import TrainSpec
from sbagents.core.zoo_config import default_config_path, lookup_entry
from sbagents.env_factory import make_team_vecs
from sbagents.errors import UsageError
from sbagents.multiagent.factory import ParallelEnvFactory
from sbagents.multiagent.preprocessing import GrayscaleObservation, ImagePreprocessing, ResizeObservation

PONG = "pettingzoo.butterfly.cooperative_pong_v6"
RAW_SHAPE = (280, 480, 3)  # cooperative_pong_v6's screen, (H, W, RGB) uint8; both paddles observe all of it


@pytest.fixture(autouse=True)
def _quiet_pygame() -> Iterator[None]:
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "You are calling render method without specifying any render mode")
        yield


def pong(**kwargs: Any) -> Any:
    """A cooperative_pong_v6 ParallelEnv that draws its screen (its observations are black without a render mode)."""
    return cooperative_pong_v6.parallel_env(render_mode="rgb_array", **kwargs)


def gray(frame: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2GRAY)


def area(frame: np.ndarray, height: int, width: int) -> np.ndarray:
    return cv2.resize(np.ascontiguousarray(frame), (width, height), interpolation=cv2.INTER_AREA)


def paired_frames(wrapper: Any, n_steps: int = 6) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """(raw, wrapped) observations of two same-seed copies, one wrapped by ``wrapper``, under the same actions:
    every agent's observation at reset and after each step, then the state."""
    raw, wrapped = pong(), wrapper(pong())
    raw_obs, _ = raw.reset(seed=3)
    obs, _ = wrapped.reset(seed=3)
    actions = [1, 2, 0]
    for t in range(n_steps + 1):
        assert set(obs) == set(raw_obs)
        for agent in obs:
            yield raw_obs[agent], obs[agent]
        if t < n_steps:
            act = {a: actions[(t + k) % 3] for k, a in enumerate(raw.agents)}
            raw_obs = raw.step(act)[0]
            obs = wrapped.step(act)[0]
    yield raw.state(), wrapped.state()


def test_raw_pong_observes_the_rgb_screen() -> None:
    env = pong()
    assert env.observation_space("paddle_0") == spaces.Box(0, 255, RAW_SHAPE, np.uint8)
    assert env.state_space == spaces.Box(0, 255, RAW_SHAPE, np.uint8)
    obs, _ = env.reset(seed=0)
    assert obs["paddle_0"].max() == 255  # paddles and ball drawn (with render_mode=None they are not)


@pytest.mark.parametrize(
    ("make", "shape", "expected"),
    [
        (lambda env: ImagePreprocessing(env, shape=[84, 84]), (84, 84, 1), lambda f: area(gray(f), 84, 84)),
        (lambda env: ImagePreprocessing(env, grayscale=False, shape=64), (64, 64, 3), lambda f: area(f, 64, 64)),
        (GrayscaleObservation, (280, 480, 1), gray),
        (lambda env: ResizeObservation(env, (42, 70)), (42, 70, 3), lambda f: area(f, 42, 70)),
    ],
    ids=["gray84", "rgb64", "grayscale", "resize"],
)
def test_spaces_and_values_equal_opencv_on_the_raw_frames(make: Any, shape: tuple[int, ...], expected: Any) -> None:
    env = make(pong())
    box = spaces.Box(0, 255, shape, np.uint8)
    assert all(env.observation_space(a) == box for a in env.possible_agents)
    assert env.state_space == box and env.observation_spaces == dict.fromkeys(env.possible_agents, box)
    n = 0
    for raw, frame in paired_frames(make):
        assert frame.shape == shape and frame.dtype == np.uint8 and box.contains(frame)
        assert np.array_equal(frame.reshape(shape), np.asarray(expected(raw)).reshape(shape))
        n += 1
    assert n == 2 * 7 + 1
    assert env.action_space("paddle_1") == spaces.Discrete(3)


def test_parallel_api_test_passes_on_the_wrapped_env() -> None:
    env = ImagePreprocessing(pong(max_cycles=60), shape=(84, 84))
    parallel_api_test(env, num_cycles=60)
    assert env.unwrapped.metadata["name"] == "cooperative_pong_v6"


class TinyImages(ParallelEnv):
    """Two agents observing (6, 8) grayscale or (6, 8, 4) RGBA images; a vector state; one step per episode."""

    metadata = {"name": "tiny_images_v0"}

    def __init__(self) -> None:
        self.possible_agents = ["flat", "rgba"]
        self.agents: list[str] = []
        self.state_space = spaces.Box(0.0, 1.0, (3,), np.float32)
        self._spaces = {"flat": spaces.Box(0, 255, (6, 8), np.uint8), "rgba": spaces.Box(0, 255, (6, 8, 4), np.uint8)}
        self.rng = np.random.default_rng(0)

    def observation_space(self, agent: str) -> spaces.Space[Any]:
        return self._spaces[agent]

    def action_space(self, agent: str) -> spaces.Space[Any]:
        return spaces.Discrete(2)

    def _obs(self) -> dict[str, np.ndarray]:
        return {a: self._spaces[a].sample() for a in self.agents}

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        self.agents = list(self.possible_agents)
        for space in self._spaces.values():
            space.seed(seed)
        return self._obs(), {a: {} for a in self.agents}

    def step(self, actions: dict[str, Any]) -> Any:
        obs = self._obs()
        done = dict.fromkeys(self.agents, True)
        self.agents = []
        return obs, dict.fromkeys(done, 1.0), done, dict.fromkeys(done, False), {a: {} for a in done}

    def state(self) -> np.ndarray:
        return np.array([0.1, 0.2, 0.3], np.float32)


def test_two_dimensional_and_rgba_images_and_a_vector_state() -> None:
    env = ImagePreprocessing(TinyImages(), grayscale=True, shape=(3, 4))
    assert env.observation_space("flat") == env.observation_space("rgba") == spaces.Box(0, 255, (3, 4, 1), np.uint8)
    assert env.state_space == spaces.Box(0.0, 1.0, (3,), np.float32)  # not an image: unchanged
    assert np.array_equal(env.state(), np.array([0.1, 0.2, 0.3], np.float32))
    inner = TinyImages()
    raw, _ = inner.reset(seed=5)
    obs, _ = env.reset(seed=5)
    assert np.array_equal(obs["flat"][:, :, 0], area(raw["flat"], 3, 4))
    assert np.array_equal(obs["rgba"][:, :, 0], area(cv2.cvtColor(raw["rgba"], cv2.COLOR_RGBA2GRAY), 3, 4))
    keep = GrayscaleObservation(TinyImages())  # a 2-D image gains its channel axis; RGBA -> one channel
    assert keep.observation_space("flat").shape == keep.observation_space("rgba").shape == (6, 8, 1)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"shape": [0, 84]}, "shape must be a positive int or"), ({"shape": [84, 84, 1]}, "shape must be"),
     ({"shape": "84"}, "shape must be")],
)
def test_bad_shape_is_a_usage_error(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(UsageError, match=message):
        ImagePreprocessing(pong(), **kwargs)


def test_non_image_observations_are_a_usage_error() -> None:
    from pettingzoo.butterfly import knights_archers_zombies_v11

    with pytest.raises(UsageError, match=r"ImagePreprocessing needs uint8 image observations .*; archer_0 observes"):
        ImagePreprocessing(knights_archers_zombies_v11.parallel_env())
    with pytest.raises(UsageError, match="wraps a PettingZoo ParallelEnv, got CartPoleEnv"):
        from gymnasium.envs.classic_control import CartPoleEnv

        ResizeObservation(CartPoleEnv())  # type: ignore[arg-type]


def test_a_gymnasium_wrapper_for_a_pettingzoo_env_is_a_usage_error() -> None:
    from gymnasium.wrappers import GrayscaleObservation as GymGrayscale

    with pytest.raises(UsageError, match="GrayscaleObservation is a Gymnasium wrapper .* ParallelEnv wrappers"):
        ParallelEnvFactory(PONG, wrappers=[(GymGrayscale, {})])
    ParallelEnvFactory(PONG, wrappers=[(ImagePreprocessing, {})])  # fine


# ---------------------------------------------------------------------------------------------- the shipped entry
def test_shipped_entry_stacks_four_84x84_gray_frames_for_cnn_policy() -> None:
    entry = lookup_entry(default_config_path("ppo"), resolve_env(PONG).config_keys)
    assert entry["policy"] == "CnnPolicy" and entry["frame_stack"] == 4
    assert entry["env_kwargs"]["render_mode"] == "rgb_array"
    assert entry["env_wrapper"] == [{"sbagents.multiagent.preprocessing.ImagePreprocessing":
                                     {"grayscale": True, "shape": [84, 84]}}]
    assert entry["policies"] == "per_agent"
    ref = resolve_env(PONG)
    exp = build_experiment(TrainSpec(algo="ppo", env=PONG), ref)
    venvs = make_team_vecs(exp, ref, 2, seed=0)
    try:
        assert list(venvs) == ["paddle_0", "paddle_1"]
        for venv in venvs.values():
            assert isinstance(venv, VecFrameStack) and venv.num_envs == 2  # 2 team copies x 1 paddle
            assert venv.observation_space == spaces.Box(0, 255, (84, 84, 4), np.uint8)
        obs = [venv.reset() for venv in venvs.values()][-1]  # the team resets once per group, in order
        assert isinstance(obs, np.ndarray) and obs.shape == (2, 84, 84, 4) and obs.dtype == np.uint8
        assert obs[..., -1].max() > 0 and not obs[..., :-1].any()  # the newest frame drawn, older ones zero
    finally:
        for venv in venvs.values():
            venv.close()


@pytest.fixture(scope="module")
def pong_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 64-step PPO run of the shipped entry (one team, 32-step rollouts of each paddle's model)."""
    logs = tmp_path_factory.mktemp("cooperative_pong")
    result = cli("train", "--algo", "ppo", "--env", PONG, "-f", str(logs), "-n", "64", "--seed", "0",
                 "-params", "n_envs:1", "n_steps:32", "batch_size:32", "n_epochs:1",
                 "--eval-freq", "-1", "--final-eval-episodes", "1", "--verbose", "0")
    assert result.returncode == 0, result.stderr
    return logs


def test_cli_trains_cnn_policy_on_stacked_frames_and_evaluates(pong_run: Path) -> None:
    run_dir = pong_run / "ppo" / "cooperative_pong_v6_1"
    config = yaml.safe_load((run_dir / "cooperative_pong_v6" / "config.yml").read_text())
    assert config["policy"] == "CnnPolicy" and config["frame_stack"] == 4 and config["n_envs"] == 1
    assert summary(run_dir)["n_timesteps"] == 64
    for paddle in ("paddle_0", "paddle_1"):  # policies: per_agent, one model per paddle
        model = PPO.load(str(run_dir / f"cooperative_pong_v6.{paddle}.zip"), device="cpu")
        assert model.observation_space == spaces.Box(0, 255, (4, 84, 84), np.uint8)  # VecTransposeImage: (C, H, W)
        assert type(model.policy.features_extractor).__name__ == "NatureCNN"
    result = cli("evaluate", "--algo", "ppo", "--env", PONG, "-f", str(pong_run), "-n", "1", "--json")
    assert result.returncode == 0, result.stderr
    report = last_json(result.stdout)
    assert report["n_episodes"] == 1 and isinstance(report["mean_return"], float)
    assert set(report["metrics"]["per_agent_return"]) == {"paddle_0", "paddle_1"}


def test_periodic_team_evaluation_of_stacked_frames(tmp_path: Path) -> None:
    result = cli("train", "--algo", "ppo", "--env", PONG, "-f", str(tmp_path), "-n", "64", "--seed", "0",
                 "-params", "n_envs:1", "n_steps:32", "batch_size:32", "n_epochs:1",
                 "--eval-freq", "32", "--eval-episodes", "1", "--final-eval-episodes", "0", "--verbose", "0")
    assert result.returncode == 0, result.stderr.strip().splitlines()[-1]
    assert (tmp_path / "ppo" / "cooperative_pong_v6_1" / "evaluations.npz").exists()


def one_line_error(capsys: pytest.CaptureFixture[str], *args: str) -> str:
    """The single stderr line of ``python -m sbagents.train args`` that fails with a usage error (run in-process)."""
    from sbagents.train import main

    with pytest.raises(SystemExit) as exit_info:
        run("python -m sbagents.train", lambda: main(list(args)))
    stderr = capsys.readouterr().err
    assert exit_info.value.code == 2 and "Traceback" not in stderr, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    return lines[0]


@pytest.mark.parametrize(
    ("params", "message"),
    [
        (["policies:shared", "agent_id:true"],
         "observation spaces of paddle_0, paddle_1 are not vectors, so an agent id cannot be appended"),
        (["env_wrapper:[gymnasium.wrappers.GrayscaleObservation]"], "is a Gymnasium wrapper"),
        (["env_wrapper:[{sbagents.multiagent.preprocessing.ResizeObservation: {shape: [-1, 84]}}]"],
         "shape must be a positive int or [height, width]"),
    ],
    ids=["agent_id", "gym_wrapper", "bad_shape"],
)
def test_layouts_images_cannot_take_are_one_line_errors(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, params: list[str], message: str
) -> None:
    line = one_line_error(capsys, "--algo", "ppo", "--env", PONG, "-f", str(tmp_path), "-n", "64", "-params", *params)
    assert message in line
    assert not list(tmp_path.rglob("*.zip"))
