"""A user's own registered env trains and evaluates via ``--gym-packages`` and ``module:EnvId``."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import yaml
from cli_helpers import cli
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import SubprocVecEnv

from sbagents.core.env_names import resolve_env

USER_ENVS = Path(__file__).resolve().parent / "user_envs"


def user_cli(module: str, *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``python -m sbagents.<module>`` with ``tests/user_envs`` (holding ``tiny_env_pkg``) on PYTHONPATH.

    A subprocess: ``--gym-packages`` imports the user's package, which would stay imported and registered in this
    process (and the evaluations below check that a fresh process imports it again)."""
    path = os.pathsep.join(p for p in (str(USER_ENVS), os.environ.get("PYTHONPATH", "")) if p)
    env = {**os.environ, "PYTHONPATH": path, "PYTHONUNBUFFERED": "1"}
    return subprocess.run(
        [sys.executable, "-m", f"sbagents.{module}", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=env,
        timeout=300,
    )


@pytest.mark.slow  # a training and two evaluate subprocesses: ~7 s
def test_user_env_trains_with_default_config_and_evaluates(tmp_path: Path) -> None:
    result = user_cli(
        "train",
        "--algo",
        "qlearning",
        "--env",
        "TinyEnv-v0",
        "--gym-packages",
        "tiny_env_pkg",
        "-f",
        "logs",
        "-n",
        "3000",
        "--seed",
        "0",
        "--verbose",
        "0",
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    run_dir = tmp_path / "logs" / "qlearning" / "TinyEnv-v0_1"
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["env"] == "TinyEnv-v0"
    # exact: seeded tabular Q-learning reaches the discrete optimum (length 5: three -1 steps and the +10 step = 7)
    assert summary["eval"]["mean_return"] == 7.0 and summary["eval"]["success_rate"] == 1.0
    config = yaml.safe_load((run_dir / "TinyEnv-v0" / "config.yml").read_text())
    assert config["learning_rate"] == 0.1 and config["gamma"] == 0.9  # qlearning.yml's `default` entry
    # evaluate: the package must be imported again (a fresh process), by flag or by module:EnvId (both at once)
    env_args = (["--env", "TinyEnv-v0", "--gym-packages", "tiny_env_pkg"], ["--env", "tiny_env_pkg:TinyEnv-v0"])
    with ThreadPoolExecutor(max_workers=2) as pool:
        evaluations = list(pool.map(lambda args: user_cli("evaluate", "--algo", "qlearning", *args, "-f", "logs", "-n",
                                                          "3", "--json", cwd=tmp_path), env_args))
    for ev in evaluations:
        assert ev.returncode == 0, ev.stderr
        report = json.loads(ev.stdout.strip().splitlines()[-1])
        assert report["env"] == "TinyEnv-v0" and report["mean_return"] == 7.0 and report["mean_length"] == 4.0


def test_module_env_id_with_own_config_and_callback(tmp_path: Path) -> None:
    conf = tmp_path / "my.yml"  # 2,000 steps: A2C's greedy policy reached the optimum 8 with seeds 1, 2 and 3
    conf.write_text(
        "TinyEnv-v0:\n"
        "  n_timesteps: 2000\n"
        "  n_envs: 4\n"
        "  learning_rate: 0.003\n"
        "  policy_kwargs: {net_arch: [32]}\n"
        "  env_kwargs: {length: 4}\n"
        "  callback:\n"
        "    - sbagents.callbacks.TransparencyCSVCallback: {path: decisions.csv}\n"
    )
    result = user_cli(
        "train",
        "--algo",
        "a2c",
        "--env",
        "tiny_env_pkg:TinyEnv-v0",
        "-conf",
        str(conf),
        "-f",
        "logs",
        "--seed",
        "1",
        "--verbose",
        "0",
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    summary = json.loads((tmp_path / "logs" / "a2c" / "TinyEnv-v0_1" / "summary.json").read_text())
    assert summary["n_timesteps"] == 2000
    # length 4: the optimum is 8 (three moves, two -1 steps and the +10 step); A2C's greedy policy is checked with
    # a margin (the goal within two extra moves)
    assert summary["eval"]["mean_return"] >= 6.0
    with (tmp_path / "decisions.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 2000 and "cell" in rows[0] and "move" in rows[0]


def test_missing_package_and_unknown_id_are_one_line_errors(tmp_path: Path) -> None:
    # in this process: the import fails, so nothing stays registered
    missing = cli(
        "train",
        "--algo",
        "qlearning",
        "--env",
        "TinyEnv-v0",
        "--gym-packages",
        "no_such_pkg_xyz",
        "-f",
        "logs",
        cwd=tmp_path,
    )
    assert missing.returncode == 2
    assert missing.stderr.strip().count("\n") == 0 and "no_such_pkg_xyz" in missing.stderr
    unknown = user_cli(
        "train",
        "--algo",
        "qlearning",
        "--env",
        "TinyEnv-v9",
        "--gym-packages",
        "tiny_env_pkg",
        "-f",
        "logs",
        cwd=tmp_path,
    )
    assert unknown.returncode == 2 and "TinyEnv-v0" in unknown.stderr  # suggests the close id
    assert unknown.stderr.strip().count("\n") == 0
    assert not (tmp_path / "logs" / "qlearning").exists() or not any(
        (tmp_path / "logs" / "qlearning").iterdir()
    )


def test_make_fn_finds_user_env_in_a_fresh_worker_process(monkeypatch: pytest.MonkeyPatch) -> None:
    """SubprocVecEnv workers start with an empty registry: ``EnvRef.make_fn`` imports the package there (a user's,
    or sbagents' own registration)."""
    monkeypatch.syspath_prepend(str(USER_ENVS))
    ref = resolve_env("TinyEnv-v0", ["tiny_env_pkg"])
    assert ref.env_id == "TinyEnv-v0" and ref.modules == ("tiny_env_pkg",)
    assert resolve_env("tiny_env_pkg:TinyEnv-v0").modules == ("tiny_env_pkg",)
    assert resolve_env("CartPole-v1").make_fn() == "CartPole-v1"
    venv = make_vec_env(
        ref.make_fn(), n_envs=1, seed=0, vec_env_cls=SubprocVecEnv, vec_env_kwargs={"start_method": "spawn"}
    )
    try:
        venv.reset()
        obs, rewards, _, _ = venv.step(np.array([1]))
        assert np.asarray(obs)[0] == 1 and rewards[0] == -1.0
    finally:
        venv.close()
    # sbagents' own ids too, where this process's __main__ (pytest here) does not import sbagents
    own = make_vec_env(resolve_env("sbagents/GridWorld-v0").make_fn(), n_envs=1, seed=0, vec_env_cls=SubprocVecEnv,
                       vec_env_kwargs={"start_method": "spawn"})
    try:
        assert np.asarray(own.reset()).shape == (1, *own.observation_space.shape)
    finally:
        own.close()
