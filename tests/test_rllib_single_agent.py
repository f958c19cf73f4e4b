"""The RLlib backend on Gymnasium envs (one agent): ``python -m sbagents.train --backend rllib --algo ALGO --env ID``
for PPO, APPO, IMPALA, DQN and SAC on tiny budgets, ``evaluate`` on the run (its module rebuilt from plain data),
the env every env runner builds (Atari preprocessing, flattened observations), user envs through
``--gym-packages``, and the one-line refusals.

Needs Ray (``pip install -e ".[test,distributed]"``; ``.ci/run`` runs these in a venv of their own with
``SBAGENTS_REQUIRE_RAY=1``, so a missing Ray fails instead of skipping).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import cli, last_json, summary

from sbagents.errors import UsageError
from sbagents.rllib import CHECKPOINT_DIR, MODULES_FILE, WEIGHTS_FILE, is_rllib_run, ray_available

pytestmark = pytest.mark.skipif(
    not ray_available() and not os.environ.get("SBAGENTS_REQUIRE_RAY"),
    reason="needs Ray RLlib: pip install -e '.[test,distributed]' (.ci/run runs these in a venv of their own)",
)
QUIET = ("--verbose", "0", "--eval-freq", "-1", "--final-eval-episodes", "3")


def _train(tmp_path: Path, algo: str, env: str, steps: int, *extra: str) -> Path:
    result = cli("train", "--backend", "rllib", "--algo", algo, "--env", env, "-n", str(steps), "-f", str(tmp_path),
                 "--seed", "0", *QUIET, *extra)
    assert result.returncode == 0, result.stderr
    (run_dir,) = (tmp_path / algo).iterdir()
    assert is_rllib_run(run_dir)
    return run_dir


def test_ppo_learns_gridworld_with_its_shipped_entry_and_evaluate_plays_the_run(tmp_path: Path) -> None:
    """The shipped ``sbagents/GridWorld-v0`` entry (30k steps, sampled in the driver) reaches the shortest path's
    return 93; ``evaluate`` rebuilds the module from its plain data; ``export`` says in one line it takes SB3 runs."""
    run_dir = _train(tmp_path, "ppo", "sbagents/GridWorld-v0", 30_000)
    s = summary(run_dir)
    assert s["backend"] == "rllib" and s["n_timesteps"] >= 30_000 and s["eval"]["mean_return"] == 93.0
    spec = json.loads((run_dir / CHECKPOINT_DIR / MODULES_FILE).read_text())
    assert spec["modules"] == {"default_policy": ["default_agent"]} and spec["algo"] == "ppo"
    report = last_json(cli("evaluate", "--algo", "ppo", "--env", "sbagents/GridWorld-v0", "-f", str(tmp_path), "-n",
                           "5", "--json").stdout)
    assert report["n_episodes"] == 5 and report["mean_return"] == 93.0 and report["success_rate"] == 1.0
    video = cli("record_video", "--algo", "ppo", "--env", "sbagents/GridWorld-v0", "-f", str(tmp_path), "-n", "20")
    assert video.returncode == 0, video.stderr
    mp4 = run_dir / "videos" / "ppo-sbagents_GridWorld-v0-step-0-to-step-20.mp4"
    rows = mp4.with_suffix(".csv").read_text().splitlines()
    assert mp4.stat().st_size > 0 and len(rows) == 21  # a header and one row per recorded step
    assert sum(float(r.split(",")[-5]) for r in rows[1:]) > 0  # the reward column: the goal is reached
    exported = last_json(cli("export", "--algo", "ppo", "--env", "sbagents/GridWorld-v0", "-f", str(tmp_path),
                             "--n-observations", "200", "--json").stdout)
    assert exported["parity_fp32"] == 0.0 and exported["n_parity_observations"] == 200
    sidecar = json.loads((run_dir / "export" / "policy.json").read_text())
    assert sidecar["algo"] == "ppo" and sidecar["observation_space"]["shape"] == [25]  # the flattened cell
    assert sidecar["preprocessing"]["env_wrapper"][0]["class"] == "gymnasium.wrappers.FlattenObservation"


@pytest.mark.parametrize(("algo", "env", "steps", "extra"), [
    ("dqn", "CartPole-v1", 600, ("-params", "num_steps_sampled_before_learning_starts:200")),
    ("appo", "CartPole-v1", 1000, ()),
    ("impala", "CartPole-v1", 1000, ()),
    ("sac", "Pendulum-v1", 400, ("-params", "num_steps_sampled_before_learning_starts:200")),
])
def test_every_algorithm_trains_and_its_run_evaluates(tmp_path: Path, algo: str, env: str, steps: int,
                                                      extra: tuple[str, ...]) -> None:
    """A module with target networks (DQN, APPO, SAC) or settings from the algorithm (DQN's dueling head) is
    rebuilt exactly (``strict`` weights); SAC's squashed actions reach the env inside its bounds; ``export`` writes
    a graph that acts as ``evaluate`` plays the module (parity 0 within float rounding)."""
    run_dir = _train(tmp_path, algo, env, steps, *extra)
    assert summary(run_dir)["n_timesteps"] >= steps
    assert (run_dir / CHECKPOINT_DIR / WEIGHTS_FILE).is_file()
    report = last_json(cli("evaluate", "--algo", algo, "--env", env, "-f", str(tmp_path), "-n", "2", "--json").stdout)
    assert report["n_episodes"] == 2 and math.isfinite(report["mean_return"])

    from sbagents.core.env_names import resolve_env
    from sbagents.rllib.checkpoints import action_settings, load_modules
    from sbagents.rllib.single_agent import SINGLE_MODULE, build_env, module_policy

    module = load_modules(run_dir / CHECKPOINT_DIR, resolve_env(env), {})[SINGLE_MODULE]
    probe = build_env(env)
    obs = np.stack([probe.observation_space.sample() for _ in range(64)])
    settings = action_settings(run_dir / CHECKPOINT_DIR)
    for greedy in (True, False):
        actions = module_policy(module, probe.action_space, greedy, settings)(obs)
        assert len(actions) == 64 and all(probe.action_space.contains(a) for a in actions)
    exported = last_json(cli("export", "--algo", algo, "--env", env, "-f", str(tmp_path), "--n-observations", "100",
                             "--json").stdout)
    assert exported["parity_fp32"] <= 1e-5 and exported["action_kind"] == ("box" if algo == "sac" else "discrete")


def test_a_user_env_through_gym_packages_reaches_the_env_runners(tmp_path: Path) -> None:
    """``--gym-packages`` (refused by RLlib runs before) is imported in every env runner process: one remote env
    runner builds the user's env from its own registration."""
    package = tmp_path / "site" / "my_corridor"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text(
        "import gymnasium as gym\n"
        "from gymnasium import spaces\n"
        "import numpy as np\n\n\n"
        "class Corridor(gym.Env):\n"
        "    observation_space = spaces.Box(0.0, 1.0, (1,), np.float32)\n"
        "    action_space = spaces.Discrete(2)\n\n"
        "    def reset(self, *, seed=None, options=None):\n"
        "        super().reset(seed=seed)\n"
        "        self.x = 0\n"
        "        return np.zeros(1, np.float32), {}\n\n"
        "    def step(self, action):\n"
        "        self.x += 1 if action == 1 else 0\n"
        "        done = self.x >= 5\n"
        "        return np.array([self.x / 5], np.float32), float(done), done, False, {'is_success': done}\n\n\n"
        "gym.register('MyCorridor-v0', entry_point=Corridor, max_episode_steps=20)\n")
    env = {**os.environ, "PYTHONPATH": f"{tmp_path / 'site'}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    # a subprocess: the user's module must not stay registered in this process, and Ray's workers inherit PYTHONPATH
    done = subprocess.run([sys.executable, "-m", "sbagents.train", "--backend", "rllib", "--algo", "ppo", "--env",
                           "MyCorridor-v0", "--gym-packages", "my_corridor", "-n", "400", "-f", str(tmp_path / "logs"),
                           "--num-env-runners", "1", "-params", "train_batch_size_per_learner:200",
                           "minibatch_size:50", *QUIET], capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    (run_dir,) = (tmp_path / "logs" / "ppo").iterdir()
    s = summary(run_dir)
    assert s["num_env_runners"] == 1 and s["n_timesteps"] >= 400 and s["eval"]["n_episodes"] == 3


def test_atari_ids_get_rllibs_preprocessing_and_its_tuned_entry() -> None:
    pytest.importorskip("ale_py", reason="Atari needs ale-py: pip install -e '.[atari]'")
    from sbagents.core.env_names import resolve_env
    from sbagents.core.options import TrainSpec
    from sbagents.rllib.experiment import build_experiment
    from sbagents.rllib.single_agent import ATARI_DIM, ATARI_STACK, env_spaces

    ref = resolve_env("PongNoFrameskip-v4")
    obs, act = env_spaces(ref, {})
    assert obs.shape == (ATARI_DIM, ATARI_DIM, ATARI_STACK) and obs.dtype == np.float32 and float(obs.high.max()) == 1
    assert act.n == 6
    exp = build_experiment(TrainSpec(algo="ppo", env="PongNoFrameskip-v4"), ref)
    assert exp.environment == {"clip_rewards": True} and exp.model["conv_filters"][0] == [16, 4, 2]


def test_observations_the_default_encoders_cannot_take_are_flattened_to_floats() -> None:
    from sbagents.rllib.single_agent import build_env

    env = build_env("sbagents/GridWorld-v0")  # Discrete(25): a one-hot float vector
    obs, _ = env.reset(seed=0)
    assert env.observation_space.shape == (25,) and obs.dtype == np.float32 and obs.sum() == 1.0
    with pytest.raises(UsageError, match="invalid env_kwargs for sbagents/GridWorld-v0"):
        build_env("sbagents/GridWorld-v0", env_kwargs={"no_such_arg": 1})


@pytest.mark.parametrize(("entry", "message"), [
    ({"policies": "per_agent"}, "policies and groups apply to PettingZoo teams"),
    ({"replay_buffer_config": {"type": "my.module.Buffer"}}, "replay_buffer_config is a mapping whose type"),
    ({"learner_class": "my.module.Learner"}, "unknown key(s) learner_class"),
])
def test_entries_for_gymnasium_envs_are_checked(entry: dict[str, object], message: str) -> None:
    from sbagents.core.env_names import resolve_env
    from sbagents.core.options import TrainSpec
    from sbagents.rllib.experiment import build_experiment

    conf = {"n_timesteps": 100, **entry}
    algo = "dqn" if "replay_buffer_config" in entry else "ppo"
    with pytest.raises(UsageError, match=message.replace("(", r"\(").replace(")", r"\)")):
        spec = TrainSpec(algo=algo, env="CartPole-v1", hyperparams=conf)
        build_experiment(spec, resolve_env("CartPole-v1"))


def test_pong_reaches_a_local_multi_node_test_cluster() -> None:
    """``rllib-pong --quick``: Atari PPO on local Ray and, through ``--address``, on ``ray.cluster_utils.Cluster``
    (a head and a worker node); both sample their steps and report their rates."""
    pytest.importorskip("ale_py", reason="Atari needs ale-py: pip install -e '.[atari]'")
    from benchmarks.speed.rllib_pong import render, run

    results = run(["--quick"])
    local, cluster = results["rows"]
    assert local["where"] == "local Ray" and cluster["where"] == "test cluster, 2 nodes"
    assert all(r["env_steps"] >= 400 and r["fps"] > 0 for r in (local, cluster))
    assert "| test cluster, 2 nodes | 1 | " in render(results)
