"""The train/evaluate CLIs end to end: learning, run dirs, determinism, concurrency, interruption."""

from __future__ import annotations

import csv
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from cli_helpers import cli, cli_subprocess, last_json, popen, summary
from stable_baselines3 import PPO

from sbagents.api import RunRef, export
from sbagents.core.run_dir import load_run
from sbagents.errors import UsageError

GRID = "sbagents/GridWorld-v0"
RUN = "sbagents_GridWorld-v0"
#: GridWorld's best return: 8 moves, 7 steps of -1 and the goal's +100. A deep-RL method's greedy policy after its
#: zoo budget is checked against it with a margin (>= 90: the goal within 11 moves), the tabular ones exactly.
OPTIMUM = 93.0
NEAR_OPTIMUM = 90.0

ZooRun = Callable[[str], tuple[subprocess.CompletedProcess[str], Path]]


@pytest.fixture(scope="module")
def zoo_run(tmp_path_factory: pytest.TempPathFactory) -> ZooRun:
    """``zoo_run(algo)``: the output and logs folder of one GridWorld run on the algorithm's zoo entry (seed 3),
    trained on first use and shared by the tests of this module that only read it."""
    runs: dict[str, tuple[subprocess.CompletedProcess[str], Path]] = {}

    def get(algo: str) -> tuple[subprocess.CompletedProcess[str], Path]:
        if algo not in runs:
            folder = tmp_path_factory.mktemp(f"zoo_{algo}")
            runs[algo] = cli("train", "--algo", algo, "--env", GRID, "-f", str(folder), "--seed", "3"), folder
        return runs[algo]

    return get


def test_default_run_prints_path_and_93(tmp_path: Path) -> None:
    # a subprocess: README command 1 as a newcomer runs it (a fresh interpreter: nothing on stderr, no warning)
    result = cli_subprocess("train", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "learned path (8 moves):" in result.stdout
    assert "return: 93" in result.stdout
    lines = result.stdout.splitlines()
    assert sum(line.startswith("eval ") for line in lines) == 10  # one line per periodic evaluation
    assert "rollout/" not in result.stdout and "Using cpu device" not in result.stdout  # SB3's tables: --verbose 2
    assert result.stderr == ""
    run_dir = tmp_path / "logs" / "qlearning" / f"{RUN}_1"
    for name in (f"{RUN}.zip", "summary.json", "0.monitor.csv", "command.txt", "evaluations.npz",
                 "best_model.zip", f"{RUN}/config.yml", f"{RUN}/args.yml"):
        assert (run_dir / name).exists(), name
    s = summary(run_dir)
    assert set(s) >= {"algo", "env", "seed", "n_timesteps", "train_seconds", "fps", "eval"}
    # exact: tabular Q-learning with the default seed reaches the discrete optimum (and README command 1 says 93)
    assert s["eval"]["mean_return"] == OPTIMUM and s["eval"]["success_rate"] == 1.0


@pytest.mark.parametrize("algo", ["qlearning", "sarsa", pytest.param("dqn", marks=pytest.mark.slow), "ppo", "a2c"])
def test_zoo_config_reaches_optimal_return(zoo_run: ZooRun, algo: str) -> None:
    """The zoo entry's budget learns GridWorld: a learning check (the full budget)."""
    result, folder = zoo_run(algo)
    assert result.returncode == 0, result.stderr
    ev = summary(folder / algo / f"{RUN}_1")["eval"]
    if algo in ("qlearning", "sarsa"):  # exact: a seeded tabular method reaches the discrete optimum
        assert ev["mean_return"] == OPTIMUM and ev["mean_length"] == 8
    else:
        assert ev["mean_return"] >= NEAR_OPTIMUM and ev["success_rate"] == 1.0, ev
    assert len(result.stdout.splitlines()) < 40 and "rollout/" not in result.stdout  # readable by default


def test_verbose_2_prints_sb3_tables_and_0_only_the_result(tmp_path: Path) -> None:
    tables = cli("train", "--algo", "ppo", "-n", "512", "-f", str(tmp_path), "--seed", "0", "--verbose", "2",
                 "-params", "n_envs:2", "n_steps:256")
    assert tables.returncode == 0 and "rollout/" in tables.stdout and "ep_rew_mean" in tables.stdout
    quiet = cli("train", "--algo", "ppo", "-n", "512", "-f", str(tmp_path), "--seed", "0", "--verbose", "0",
                "-params", "n_envs:2", "n_steps:256")
    assert quiet.returncode == 0 and not any(line.startswith("eval ") for line in quiet.stdout.splitlines())
    assert quiet.stdout.startswith("run dir: ")


def test_evaluate_json_and_table(zoo_run: ZooRun) -> None:
    trained, tmp_path = zoo_run("ppo")  # evaluate only reads the run
    assert trained.returncode == 0, trained.stderr
    result = cli("evaluate", "--algo", "ppo", "--env", "GridWorld-v0", "-f", str(tmp_path), "-n", "3", "--json")
    assert result.returncode == 0, result.stderr
    report = last_json(result.stdout)
    assert {k: v for k, v in report.items() if k not in ("mean_return", "mean_length")} == {
        "env": GRID, "algo": "ppo", "n_episodes": 3, "std_return": 0.0, "success_rate": 1.0, "metrics": {}}
    assert report["mean_return"] >= NEAR_OPTIMUM and report["mean_return"] + report["mean_length"] == OPTIMUM + 8
    table = cli("evaluate", "--algo", "ppo", "--env", GRID, "-f", str(tmp_path), "--load-best", "--exp-id", "1")
    assert table.returncode == 0 and "mean_return" in table.stdout
    rendered = cli("evaluate", "--algo", "ppo", "--env", GRID, "-f", str(tmp_path), "-n", "1", "--render")
    assert "A . . . ." in rendered.stdout


def test_overrides_and_env_kwargs_reach_the_run(tmp_path: Path) -> None:
    result = cli("train", "--algo", "ppo", "-f", str(tmp_path), "--seed", "0", "-n", "512", "--verbose", "0",
                 "-params", "learning_rate:1e-3", "n_envs:2", "--env-kwargs", "max_steps:20", "--eval-freq", "-1")
    assert result.returncode == 0, result.stderr
    run_dir = tmp_path / "ppo" / f"{RUN}_1"
    config = yaml.safe_load((run_dir / RUN / "config.yml").read_text())
    assert config["learning_rate"] == 1e-3 and config["n_envs"] == 2 and config["env_kwargs"] == {"max_steps": 20}
    assert not (run_dir / "evaluations.npz").exists()
    assert {p.name for p in run_dir.glob("*.monitor.csv")} == {"0.monitor.csv", "1.monitor.csv"}
    assert max(summary(run_dir)["eval"]["mean_length"], 0) <= 20


def test_continue_training(tmp_path: Path) -> None:
    first_run = cli("train", "--algo", "ppo", "-f", str(tmp_path), "--seed", "0", "-n", "1024", "--verbose", "0")
    assert first_run.returncode == 0, first_run.stderr
    first = tmp_path / "ppo" / f"{RUN}_1" / f"{RUN}.zip"
    result = cli("train", "--algo", "ppo", "-f", str(tmp_path), "--seed", "0", "-n", "1024", "-i", str(first),
                 "--verbose", "0")
    assert result.returncode == 0, result.stderr
    assert PPO.load(tmp_path / "ppo" / f"{RUN}_2" / f"{RUN}.zip").num_timesteps >= 2048


def monitor_rows(run_dir: Path) -> list[tuple[str, str]]:
    with open(run_dir / "0.monitor.csv") as handle:
        next(handle)  # '#{"t_start": ...}' header line holds a wall-clock timestamp
        return [(row["r"], row["l"]) for row in csv.DictReader(handle)]


def test_same_seed_same_results(tmp_path: Path) -> None:
    for _ in range(2):
        result = cli("train", "--algo", "dqn", "-f", str(tmp_path), "--seed", "5", "-n", "2000", "--verbose", "0")
        assert result.returncode == 0, result.stderr
    a, b = tmp_path / "dqn" / f"{RUN}_1", tmp_path / "dqn" / f"{RUN}_2"
    assert summary(a)["eval"] == summary(b)["eval"]
    assert monitor_rows(a) == monitor_rows(b) and len(monitor_rows(a)) > 10
    evals = [cli("evaluate", "--algo", "dqn", "--env", GRID, "-f", str(tmp_path), "--exp-id", str(k), "--json",
                 "--stochastic", "--seed", "9") for k in (1, 2)]
    assert last_json(evals[0].stdout) == last_json(evals[1].stdout)


@pytest.mark.slow  # two new interpreters
def test_concurrent_runs_get_distinct_dirs(tmp_path: Path) -> None:
    # subprocesses: two processes racing for the next run dir is the point
    procs = [popen("train", "--algo", "ppo", "-f", str(tmp_path), "-n", "1024", "--verbose", "0") for _ in range(2)]
    for proc in procs:
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err
    dirs = sorted(p.name for p in (tmp_path / "ppo").iterdir())
    assert dirs == [f"{RUN}_1", f"{RUN}_2"]
    for d in dirs:
        assert (tmp_path / "ppo" / d / f"{RUN}.zip").exists()



def test_on_policy_evaluates_at_most_once_per_rollout(tmp_path: Path) -> None:
    """A budget of 4 rollouts with ``--eval-freq 8``: PPO's policy changes only between rollouts, so it is
    evaluated once per rollout (64 env steps), not every 8 steps."""
    result = cli("train", "--algo", "ppo", "-f", str(tmp_path), "--seed", "0", "-n", "256", "--verbose", "0",
                 "-params", "n_steps:64", "batch_size:64", "n_envs:1", "--eval-freq", "8", "--eval-episodes", "1")
    assert result.returncode == 0, result.stderr
    timesteps = np.load(tmp_path / "ppo" / f"{RUN}_1" / "evaluations.npz")["timesteps"]
    assert list(timesteps) == [64, 128, 192, 256]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_interrupt_keeps_model_and_logs(tmp_path: Path, sig: signal.Signals) -> None:
    # a subprocess: the signal's delivery to a running training is the point
    # --eval-freq 1024: the first evaluation after one rollout (the default for 10M steps waits 25,000 steps)
    proc = popen("train", "--algo", "ppo", "-f", str(tmp_path), "-n", "10000000", "--seed", "0", "--verbose", "0",
                 "--eval-freq", "1024")
    run_dir = tmp_path / "ppo" / f"{RUN}_1"
    deadline = time.time() + 120
    while not (run_dir / "evaluations.npz").exists():  # training is under way once an evaluation ran
        assert proc.poll() is None and time.time() < deadline, proc.communicate()
        time.sleep(0.2)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert f"model and logs saved in {run_dir}" in out
    s = summary(run_dir)
    assert s["interrupted"] is True and s["n_timesteps"] > 0
    model = PPO.load(run_dir / f"{RUN}.zip")
    assert model.num_timesteps == s["n_timesteps"]
    lines = (run_dir / "0.monitor.csv").read_text().splitlines()
    assert len(lines) > 2 and all(len(line.split(",")) == 3 for line in lines[1:])


def test_vec_env_choices_give_identical_runs(tmp_path: Path) -> None:
    rows = {}
    for k, vec_env in enumerate(["dummy", "subproc", "batched"], start=1):
        result = cli("train", "--algo", "ppo", "-f", str(tmp_path), "--seed", "2", "-n", "2048", "--verbose", "0",
                     "--vec-env", vec_env, "-params", "n_envs:2", "--eval-freq", "-1")
        assert result.returncode == 0, result.stderr
        run_dir = tmp_path / "ppo" / f"{RUN}_{k}"
        assert yaml.safe_load((run_dir / RUN / "args.yml").read_text())["vec_env"] == vec_env
        rows[vec_env] = monitor_rows(run_dir)
    assert len(rows["dummy"]) > 5
    assert rows["dummy"] == rows["subproc"] == rows["batched"]


def test_list_progress_tensorboard_and_checkpoints(tmp_path: Path) -> None:
    listing = cli("train", "--list")
    assert listing.returncode == 0
    for name in ("sbagents/GridWorld-v0", "sbagents/SmartHome-v0", "sbagents/RobustPickAndPlace-v0",
                 "treasure_hunt_v0", "qlearning", "tqc", "crossq"):
        assert name in listing.stdout
    # two rollouts of 2 x 128 steps, a checkpoint after each
    result = cli("train", "--algo", "ppo", "-f", str(tmp_path), "--seed", "0", "-n", "512",
                 "-P", "-tb", str(tmp_path / "tb"), "--save-freq", "256", "-params", "n_envs:2")
    assert result.returncode == 0, result.stderr
    assert "512/512" in result.stderr and "step/s" in result.stderr  # -P: the bar, though stderr is a pipe
    run_dir = tmp_path / "ppo" / f"{RUN}_1"
    assert sorted(p.name for p in run_dir.glob("rl_model_*_steps.zip")) == ["rl_model_256_steps.zip",
                                                                            "rl_model_512_steps.zip"]
    run = ("evaluate", "--algo", "ppo", "--env", GRID, "-f", str(tmp_path), "-n", "2", "--json")
    checkpoint = cli(*run, "--load-checkpoint", "256")
    assert checkpoint.returncode == 0, checkpoint.stderr
    assert last_json(checkpoint.stdout)["n_episodes"] == 2
    missing = cli(*run, "--load-checkpoint", "999")
    assert missing.returncode == 2 and "no checkpoint after 999 steps" in missing.stderr
    assert "saved: 256, 512" in missing.stderr and "Traceback" not in missing.stderr
    both = cli(*run, "--load-checkpoint", "256", "--load-best")
    assert both.returncode == 2 and "not allowed with argument" in both.stderr
    export(RunRef("ppo", GRID, tmp_path, checkpoint=256), n_observations=20)  # not into the final model's export/
    assert (run_dir / "export_checkpoint_256" / "policy.onnx").is_file() and not (run_dir / "export").exists()
    with pytest.raises(UsageError, match="give one of them"):  # the Python API refuses both as the CLI does
        RunRef("ppo", GRID, tmp_path, load_best=True, checkpoint=256)
    loaded = load_run(RunRef("ppo", GRID, tmp_path, checkpoint=256))
    assert loaded.model_path.name == "rl_model_256_steps.zip"
    assert loaded.stats_path is None  # GridWorld's entry does not normalize: no statistics to load
    weights = [p.detach() for p in loaded.model.policy.parameters()]
    saved = PPO.load(run_dir / "rl_model_256_steps.zip", device="cpu").policy.parameters()
    final = PPO.load(run_dir / f"{RUN}.zip", device="cpu").policy.parameters()
    assert all(torch.equal(w, s.detach()) for w, s in zip(weights, saved, strict=True))
    assert not all(torch.equal(w, f.detach()) for w, f in zip(weights, final, strict=True))
    assert list((tmp_path / "tb").rglob("events.out.tfevents.*"))
