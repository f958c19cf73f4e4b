"""Kuka learning benchmark: its zoo entries resolve, the book's DDPG entry trains, the report is right."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
import torch
from stable_baselines3 import DDPG, HerReplayBuffer

from sbagents.api import EvalOptions, ExecOptions, OutputOptions, TrainSpec, train
from sbagents.core.experiment import resolve
from sbagents.core.zoo_config import lookup_entry

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "benchmarks" / "configs"
#: (config file, algo, env ids it must hold)
ENTRIES = [
    ("kuka.yml", "sac", ["sbagents/PickAndPlace-v0", "PandaPushDense-v3", "sbagents/PickAndPlaceGoal-v0"]),
    ("kuka_ddpg.yml", "ddpg", ["sbagents/PickAndPlace-v0"]),
    ("kuka_td3.yml", "td3", ["sbagents/PickAndPlace-v0", "sbagents/PickAndPlaceGoal-v0"]),
    ("kuka_tqc.yml", "tqc", ["sbagents/PickAndPlace-v0", "sbagents/PickAndPlaceGoal-v0", "PandaPush-v3"]),
]


def _bench_module() -> ModuleType:
    spec = importlib.util.spec_from_file_location("kuka_learning", ROOT / "benchmarks" / "kuka_learning.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses need the module registered
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(("conf", "algo", "env_ids"), ENTRIES)
def test_entries_resolve(conf: str, algo: str, env_ids: list[str]) -> None:
    for env_id in env_ids:
        exp = resolve(algo, env_id, lookup_entry(CONFIGS / conf, env_id), f"{conf}:{env_id}")
        assert exp.n_timesteps == 300_000 or algo == "ddpg"
        goal = "Goal" in env_id or env_id.startswith("Panda")
        assert exp.policy == ("MultiInputPolicy" if goal else "MlpPolicy")
        her = exp.algo_kwargs.get("replay_buffer_class")
        assert (her is HerReplayBuffer) == (goal and env_id != "PandaPushDense-v3")
        if not goal:
            assert exp.env_kwargs["control"] == "ee" and exp.env_kwargs["reward_type"] == "dense"


def test_book_ddpg_entry_runs(tmp_path: Path) -> None:
    torch.set_num_threads(1)
    exp = resolve("ddpg", "sbagents/PickAndPlace-v0",
                  lookup_entry(CONFIGS / "kuka_ddpg.yml", "sbagents/PickAndPlace-v0"), "kuka_ddpg.yml")
    assert exp.algo_kwargs["policy_kwargs"]["net_arch"] == [256, 128]
    assert exp.algo_kwargs["batch_size"] == 64
    spec = TrainSpec("ddpg", "sbagents/PickAndPlace-v0", 150, {"learning_starts": 100},
                     conf_file=CONFIGS / "kuka_ddpg.yml")
    result = train(spec, OutputOptions(tmp_path), EvalOptions(eval_freq=-1, final_eval_episodes=0),
                   ExecOptions(seed=0, verbose=0))
    model = result.model
    assert isinstance(model, DDPG) and model.num_timesteps == 150
    assert model.actor.mu[0].in_features == 12  # book observation Box(12)


def test_report_tables_and_plot(tmp_path: Path) -> None:
    bench = _bench_module()
    runs = []
    for label, env_id, succ in [("ours", "sbagents/PickAndPlace-v0", [0.0, 0.5, 1.0]),
                                ("panda-gym", "PandaPushDense-v3", [0.25, 0.25])]:
        run_dir = tmp_path / label
        run_dir.mkdir()
        n = len(succ)
        successes = np.array([[k < round(4 * s) for k in range(4)] for s in succ])
        np.savez(run_dir / "evaluations.npz", timesteps=np.arange(1, n + 1) * 1000,
                 results=-np.ones((n, 4)), ep_lengths=np.full((n, 4), 50), successes=successes)
        (run_dir / "summary.json").write_text(json.dumps(
            {"algo": "sac", "env": env_id, "n_timesteps": n * 1000, "train_seconds": 10.0, "fps": 100.0 * n,
             "eval": {"success_rate": succ[-1], "n_episodes": 50}}))
        (run_dir / "command.txt").write_text(f"python -m sbagents.train --env {env_id}")
        runs.append((label, str(run_dir)))
    text = bench.report(runs, tmp_path / "out" / "kuka", "title")
    assert (tmp_path / "out" / "kuka.png").stat().st_size > 10_000
    assert (tmp_path / "out" / "kuka.md").read_text() == text
    rows = [[c.strip() for c in line.strip().strip("|").split("|")] for line in text.splitlines()
            if line.startswith("|") and not line.startswith("|-")]
    by_label = {r[0]: r for r in rows}
    # steps, best and last success, final evaluation (episodes), train seconds, fps: the numbers of the runs
    assert {"3000", "100%", "100% (50)", "10", "300"} <= set(by_label["ours"])
    assert {"2000", "25%", "25% (50)", "10", "200"} <= set(by_label["panda-gym"])
    curve = {r[0]: r[1:] for r in rows if r[0].isdigit()}  # success % per evaluation step, ours then panda-gym
    assert curve["2000"][:2] == ["50", "25"] and curve["3000"][:2] == ["100", ""]
    assert "--env PandaPushDense-v3" in text
