"""``best_model.zip`` is kept with the VecNormalize statistics of its moment (``vecnormalize_best.npz``), which
``--load-best`` (evaluate, export, video) and ``-i best_model.zip`` use; before, they read the final statistics,
which had moved on since the best evaluation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run_main

from sbagents.core.run_dir import RunRef, load_run
from sbagents.state_files import BEST_VECNORMALIZE_FILE, VECNORMALIZE_FILE


def test_the_best_model_keeps_the_statistics_of_its_moment(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    logs = tmp_path / "logs"
    # a fixed policy (learning rate 0) whose returns move only with the normalization statistics: with this seed the
    # best evaluation is an early one (768 steps), so the final statistics are not the best model's
    code = run_main("train", "--algo", "ppo", "--env", "CartPole-v1", "-n", "2048", "--eval-freq", "256",
                    "--eval-episodes", "2", "--final-eval-episodes", "0", "--verbose", "0", "--seed", "1", "-f",
                    str(logs), "-params", "normalize:True", "n_envs:1", "n_steps:256", "batch_size:64", "n_epochs:1",
                    "learning_rate:0.0")
    assert code == 0, capsys.readouterr().err
    (run_dir,) = (logs / "ppo").iterdir()
    best, final = run_dir / BEST_VECNORMALIZE_FILE, run_dir / VECNORMALIZE_FILE
    assert best.is_file() and final.is_file() and (run_dir / "best_model.zip").is_file()
    with np.load(run_dir / "evaluations.npz") as evaluations:
        means = evaluations["results"].mean(axis=1)
        best_step = int(evaluations["timesteps"][int(np.argmax(means))])  # SB3 keeps the first best
    with np.load(best) as b, np.load(final) as f:
        best_count, final_count = float(b["ret_rms/count"]), float(f["ret_rms/count"])
    assert best_step < 2048
    assert abs(best_count - best_step) < 1 and abs(final_count - 2048) < 1  # statistics of that step, and the last
    ref = RunRef(algo="ppo", env="CartPole-v1", log_folder=str(logs), load_best=True)
    assert load_run(ref).stats_path == best
    assert load_run(RunRef(algo="ppo", env="CartPole-v1", log_folder=str(logs))).stats_path == final


def test_each_group_best_model_keeps_the_statistics_of_its_moment(tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """A run of one model per group: ``best_model.<group>.zip`` with ``vecnormalize_best.<group>.npz`` of the same
    evaluation, which ``--load-best`` reads."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent / "user_envs"))
    try:
        logs = tmp_path / "logs"
        code = run_main("train", "--algo", "ppo", "--env", "tiny_marl_pkg.relay_v0", "-n", "3072", "--eval-freq",
                        "384", "--eval-episodes", "2", "--final-eval-episodes", "0", "--verbose", "0", "--seed", "0",
                        "-f", str(logs), "-params", "policies:per_group", "normalize:True", "n_envs:1", "n_steps:32",
                        "batch_size:32", "n_epochs:1")
        assert code == 0, capsys.readouterr().err
        (run_dir,) = (logs / "ppo").iterdir()
        for group in ("scout", "worker"):
            assert (run_dir / f"best_model.{group}.zip").is_file()
            assert (run_dir / f"vecnormalize_best.{group}.npz").is_file()
        with np.load(run_dir / "evaluations.npz") as evaluations:
            means = evaluations["results"].mean(axis=1)
            best_team_step = int(evaluations["timesteps"][int(np.argmax(means))]) // 3  # 3 agents per team step
        with np.load(run_dir / "vecnormalize_best.worker.npz") as b:
            assert abs(float(b["ret_rms/count"]) - 2 * best_team_step) < 2 * 32 + 1  # the worker's slots then
        loaded = load_run(RunRef(algo="ppo", env="tiny_marl_pkg.relay_v0", log_folder=str(logs), load_best=True))
        assert loaded.stats_paths == {g: run_dir / f"vecnormalize_best.{g}.npz" for g in ("scout", "worker")}
        final = load_run(RunRef(algo="ppo", env="tiny_marl_pkg.relay_v0", log_folder=str(logs)))
        assert final.stats_paths == {g: run_dir / f"vecnormalize.{g}.npz" for g in ("scout", "worker")}
    finally:
        sys.path.remove(str(Path(__file__).resolve().parent / "user_envs"))
