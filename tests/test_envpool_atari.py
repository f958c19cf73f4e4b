"""``--vec-env envpool`` (:mod:`sbagents.atari`): EnvPool's C++ Atari in place of ``AtariWrapper`` on the ALE env.

- on fixed action sequences, EnvPool gives the rewards, episode ends and (all but a few pixels of) the observations
  of SB3's own ``MaxAndSkipEnv`` + ``WarpFrame`` + ``ClipRewardEnv`` on the ALE env, with the reset EnvPool does;
- monitor rows and ``info["episode"]`` carry whole games with unclipped scores; seeds repeat episodes;
- DQN, QR-DQN, PPO and A2C train on it, and the trained model evaluates and records on the plain ALE env (export
  refuses it as it refuses every Atari run);
- bad input is one line and exit 2.

Skipped without EnvPool (``pip install -e ".[atari]"``), unless ``SBAGENTS_REQUIRE_ENVPOOL=1`` (``.ci/run`` sets it
after installing the extra), where a missing EnvPool fails. The error-path tests always run.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch
import yaml
from cli_helpers import check_error, cli, last_json, run_main, summary
from stable_baselines3.common.atari_wrappers import ClipRewardEnv, MaxAndSkipEnv, WarpFrame
from stable_baselines3.common.vec_env import VecFrameStack

from sbagents.atari import envpool_support
from sbagents.atari.envpool_support import AtariSettings, check_envpool, envpool_installed, training_vec_env
from sbagents.core.env_names import resolve_env
from sbagents.core.experiment import build_experiment
from sbagents.core.monitor_files import read_monitor_files
from sbagents.core.options import TrainSpec
from sbagents.env_factory import make_vec
from sbagents.errors import UsageError

PONG, BREAKOUT = "PongNoFrameskip-v4", "BreakoutNoFrameskip-v4"
REQUIRED = os.environ.get("SBAGENTS_REQUIRE_ENVPOOL") == "1"
needs_envpool = pytest.mark.skipif(not envpool_installed() and not REQUIRED,
                                   reason='needs EnvPool: pip install -e ".[atari]"')
torch.set_num_threads(1)


class EnvPoolReset(gym.Wrapper[Any, Any, Any, Any]):
    """The reset EnvPool does with ``noop_max=1`` in a FIRE game: a new game only after a real game end (a lost
    life goes on), then one FIRE frame. Stands in for AtariWrapper's NoopReset/FireReset/EpisodicLife resets, which
    EnvPool does differently (see sbagents.atari.envpool_vec_env)."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self.game_over = True

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.game_over = terminated or truncated
        return obs, reward, terminated, truncated, info

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        if self.game_over:
            self.env.reset(**kwargs)
        obs, _, _, _, info = self.env.step(1)
        return obs, info


class LifeLoss(gym.Wrapper[Any, Any, Any, Any]):
    """EpisodicLifeEnv's episode end (a lost life, lives left) without its reset; keeps the raw game score."""

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self.lives = self.env.unwrapped.ale.lives()  # type: ignore[attr-defined]
        return obs, info

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        lives = self.env.unwrapped.ale.lives()  # type: ignore[attr-defined]
        info["raw_reward"] = reward
        terminated = terminated or 0 < lives < self.lives
        self.lives = lives
        return obs, reward, terminated, truncated, info


def reference_env(env_id: str) -> gym.Env[Any, Any]:
    """SB3's frame skip + max-pool, 84x84 grey frames and reward clipping over the ALE env, EnvPool's resets."""
    resolve_env(env_id)  # registers the ALE ids
    inner = MaxAndSkipEnv(EnvPoolReset(gym.make(env_id)), skip=4)
    return ClipRewardEnv(WarpFrame(LifeLoss(inner), 84))


@needs_envpool
@pytest.mark.parametrize(("env_id", "game", "n_steps"), [(PONG, "pong", 1200), (BREAKOUT, "breakout", 600)])
def test_same_steps_as_sb3_wrappers_on_fixed_actions(env_id: str, game: str, n_steps: int, tmp_path: Path) -> None:
    from sbagents.atari.envpool_vec_env import EnvPoolAtariVecEnv

    ref = reference_env(env_id)
    vec = EnvPoolAtariVecEnv(env_id, 1, AtariSettings(game, noop_max=1), seed=0, monitor_dir=str(tmp_path))
    rng = np.random.default_rng(0)
    frames = [(vec.reset()[0, 0], ref.reset(seed=0)[0][:, :, 0])]
    dones, games, score, steps = 0, [], 0.0, 0
    for t in range(n_steps):
        action = int(rng.integers(int(vec.action_space.n)))  # type: ignore[attr-defined]
        obs, rewards, done, infos = vec.step(np.array([action]))
        ref_obs, ref_reward, terminated, truncated, info = ref.step(action)
        score, steps = score + info["raw_reward"], steps + 1
        assert (rewards[0], bool(done[0])) == (ref_reward, terminated or truncated), f"step {t}"
        if done[0]:
            dones += 1
            frames.append((infos[0]["terminal_observation"][0], ref_obs[:, :, 0]))
            if ref.unwrapped.ale.game_over():  # type: ignore[attr-defined]
                assert infos[0]["episode"]["r"] == score and infos[0]["episode"]["l"] == 4 * steps
                games.append(infos[0]["episode"])
                score, steps = 0.0, 0
            else:  # a lost life: the game (and its score) goes on
                assert "episode" not in infos[0]
            ref_obs, _ = ref.reset()
        frames.append((obs[0, 0], ref_obs[:, :, 0]))
    vec.close()
    diff = np.abs(np.stack([a.astype(np.int16) - b for a, b in frames]))
    # grey max-pool and the ALE palette's luminance vs RGB max-pool and OpenCV's: a few pixels of moving objects
    assert (diff > 0).mean() < 1e-3, f"{(diff > 0).mean():.2e} of the pixels differ"
    assert dones >= 1 and games, "the sequence should end a game"
    rows = read_monitor_files(tmp_path)
    assert list(rows.returns) == [g["r"] for g in games] and list(rows.lengths) == [g["l"] for g in games]


@needs_envpool
def test_seeds_repeat_episodes_and_reseeding_rebuilds() -> None:
    from sbagents.atari.envpool_vec_env import EnvPoolAtariVecEnv

    def frames(vec: EnvPoolAtariVecEnv) -> np.ndarray:
        rng = np.random.default_rng(1)
        out = [vec.reset()]
        out += [vec.step(rng.integers(0, 6, size=4))[0] for _ in range(40)]
        return np.stack(out)

    settings = AtariSettings("pong")  # 30 random no-ops: the seed decides them
    a, b, c = (EnvPoolAtariVecEnv(PONG, 4, settings, seed=s) for s in (3, 3, 4))
    first = frames(a)
    assert np.array_equal(first, frames(b))
    assert not np.array_equal(first, frames(c))
    assert c.seed(3) == [3, 4, 5, 6]
    assert np.array_equal(frames(c), first)  # the next reset starts over with seed 3
    for vec in (a, b, c):
        vec.close()


@needs_envpool
def test_make_vec_envpool_is_the_default_paths_observation() -> None:
    ref = resolve_env(PONG)
    exp = build_experiment(TrainSpec("ppo", PONG), ref)
    assert training_vec_env("auto", exp, ref) == "envpool"
    venv = make_vec(exp, ref, 2, seed=0, vec_env="envpool")
    assert isinstance(venv, VecFrameStack) and venv.observation_space.shape == (4, 84, 84)  # channel-first
    obs = venv.reset()
    assert obs.shape == (2, 4, 84, 84) and obs.dtype == np.uint8
    assert venv.env_is_wrapped(gym.Wrapper) == [True, True]  # Monitor's contract: evaluation counts games
    with pytest.raises(ValueError, match="0..5"):
        venv.step(np.array([0, 6]))
    venv.close()


def test_training_vec_env_keeps_other_choices(monkeypatch: pytest.MonkeyPatch) -> None:
    cart = resolve_env("CartPole-v1")
    assert training_vec_env("auto", build_experiment(TrainSpec("ppo", "CartPole-v1"), cart), cart) == "auto"
    ref = resolve_env(PONG)
    exp = build_experiment(TrainSpec("ppo", PONG), ref)
    assert training_vec_env("subproc", exp, ref) == "subproc"
    monkeypatch.setattr(envpool_support, "envpool_installed", lambda: False)
    assert training_vec_env("auto", exp, ref) == "auto"
    with pytest.raises(UsageError, match=r"sbagents\[atari\]"):
        check_envpool(exp, ref)
    exp = dataclasses.replace(exp, env_wrapper=[])
    with pytest.raises(UsageError, match="AtariWrapper alone"):
        check_envpool(exp, ref)


def test_envpool_on_a_non_atari_env_is_one_line(tmp_path: Path) -> None:
    code = run_main("train", "--algo", "ppo", "--env", "CartPole-v1", "--vec-env", "envpool", "-n", "64",
                    "-f", str(tmp_path))
    assert code == 2
    result = cli("train", "--algo", "ppo", "--env", "CartPole-v1", "--vec-env", "envpool", "-n", "64",
                 "-f", str(tmp_path))
    check_error(result.returncode, result.stderr, "--vec-env envpool runs ALE")
    assert not (tmp_path / "ppo").exists() or not any((tmp_path / "ppo").iterdir())


@needs_envpool
@pytest.mark.parametrize(("algo", "params"), [
    ("dqn", ["buffer_size:1000", "learning_starts:100", "n_envs:2"]),
    ("qrdqn", ["buffer_size:1000", "learning_starts:100"]),
    ("a2c", ["n_envs:4"]),
    ("pqn", ["n_envs:4", "n_steps:16", "batch_size:32"]),  # parallel Q-learning: CleanRL's pqn_atari_envpool path
])
def test_off_policy_and_a2c_train_on_envpool(algo: str, params: list[str], tmp_path: Path) -> None:
    code = run_main("train", "--algo", algo, "--env", PONG, "-n", "200", "-f", str(tmp_path), "--seed", "0",
                    "--eval-freq", "-1", "--final-eval-episodes", "0", "--verbose", "0", "-params", *params)
    assert code == 0
    run_dir = tmp_path / algo / f"{PONG}_1"
    args = yaml.safe_load((run_dir / PONG / "args.yml").read_text())
    assert args["vec_env"] == "envpool"  # auto picks EnvPool for Atari ids once it is installed
    assert summary(run_dir)["n_timesteps"] >= 200


@pytest.fixture(scope="module")
def ppo_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    logs = tmp_path_factory.mktemp("envpool-ppo")
    result = cli("train", "--algo", "ppo", "--env", PONG, "--vec-env", "envpool", "-f", str(logs), "-n", "256",
                 "--seed", "0", "--eval-freq", "128", "--eval-episodes", "1", "--final-eval-episodes", "1",
                 "--verbose", "0", "-params", "n_envs:4", "n_steps:32", "batch_size:64", "n_epochs:1")
    assert result.returncode == 0, result.stderr
    return logs


@needs_envpool
def test_envpool_model_evaluates_and_records_on_the_ale_env(ppo_run: Path, tmp_path: Path) -> None:
    run_dir = ppo_run / "ppo" / f"{PONG}_1"
    config = yaml.safe_load((run_dir / PONG / "config.yml").read_text())
    assert config["env_wrapper"] == ["stable_baselines3.common.atari_wrappers.AtariWrapper"]  # what evaluation uses
    with np.load(run_dir / "evaluations.npz") as evals:  # the periodic evaluation ran on EnvPool: whole games
        assert evals["results"].shape[1] == 1 and abs(float(evals["results"][-1, 0])) <= 21
        assert int(evals["ep_lengths"][-1, 0]) >= 21 * 50  # frames of a game of at least 21 points
    result = cli("evaluate", "--algo", "ppo", "--env", PONG, "-f", str(ppo_run), "-n", "1", "--json")
    assert result.returncode == 0, result.stderr
    report = last_json(result.stdout)
    final = summary(run_dir)["eval"]  # the final evaluation of training: the plain ALE env, same seed
    assert (report["mean_return"], report["mean_length"]) == (final["mean_return"], final["mean_length"])
    assert -21 <= report["mean_return"] <= 21 and report["mean_length"] >= 21 * 50
    result = cli("record_video", "--algo", "ppo", "--env", PONG, "-f", str(ppo_run), "-n", "30", "-o",
                 str(tmp_path / "video"))
    assert result.returncode == 0, result.stderr
    assert any(p.stat().st_size > 1000 for p in (tmp_path / "video").glob("*.mp4"))
    # export: the policy as it works inside AtariWrapper + the frame stack, parity on the plain ALE env's observations
    result = cli("export", "--algo", "ppo", "--env", PONG, "-f", str(ppo_run), "--out", str(tmp_path / "onnx"),
                 "--n-observations", "100")
    assert result.returncode == 0, result.stderr
    assert "parity fp32: max abs action difference 0.00e+00 over 100 observations" in result.stdout
    assert "works inside AtariWrapper + 4-frame stack" in result.stdout


def test_envpool_threads_default_to_one_per_env_up_to_the_cpus_this_process_may_use() -> None:
    """EnvPool would count the host's CPUs; a container or ``taskset`` allows fewer."""
    from sbagents.atari.envpool_vec_env import default_threads

    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    assert default_threads(1) == 1 and default_threads(0) == 1 and default_threads(10_000) == cpus
