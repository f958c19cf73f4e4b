"""Kuka learning benchmark: its zoo entries resolve, the book's DDPG entry trains, the report is right."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from stable_baselines3 import DDPG, HerReplayBuffer

from benchmarks.learning import kuka_curves, kuka_learning
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
    curves = []
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
        curves.append(kuka_curves.load_curve(label, run_dir))
    kuka_curves.plot_curves(curves, tmp_path / "out" / "kuka.png", "title")
    assert (tmp_path / "out" / "kuka.png").stat().st_size > 10_000
    report = {"key": "main", "seed": 0, "n_episodes": 4, "runs": [kuka_curves.curve_run(c) for c in curves]}
    results = json.loads(json.dumps({"reports": [report], "blocks": [{"text": "## title"}, {"summary": "main"},
                                                                     {"curve": "main"}, {"commands": "main"}]}))
    text = kuka_curves.render_blocks(results)
    assert text.startswith("## title\n\n1 seed (seed 0) per run") and "(4 deterministic episodes)" in text
    rows = [[c.strip() for c in line.strip().strip("|").split("|")] for line in text.splitlines()
            if line.startswith("|") and not line.startswith("|-")]
    by_label = {r[0]: r for r in rows}
    # steps, best and last success, final evaluation (episodes), train seconds, fps: the numbers of the runs
    assert {"3000", "100%", "100% (50)", "10", "300"} <= set(by_label["ours"])
    assert {"2000", "25%", "25% (50)", "10", "200"} <= set(by_label["panda-gym"])
    curve = {r[0]: r[1:] for r in rows if r[0].isdigit()}  # success % per evaluation step, ours then panda-gym
    assert curve["2000"][:2] == ["50", "25"] and curve["3000"][:2] == ["100", ""]
    assert "--env PandaPushDense-v3" in text


def _fake_run_dir(run_dir: Path, env_id: str, success: list[float], folder: Path) -> None:
    """A finished ``sbagents.train`` run dir: 4 evaluation episodes per point, a summary and its command."""
    run_dir.mkdir(parents=True)
    n = len(success)
    np.savez(run_dir / "evaluations.npz", timesteps=np.arange(1, n + 1) * 1000, results=-np.ones((n, 4)),
             ep_lengths=np.full((n, 4), 50),
             successes=np.array([[k < round(4 * s) for k in range(4)] for s in success]))
    (run_dir / "summary.json").write_text(json.dumps(
        {"algo": "sac", "env": env_id, "n_timesteps": n * 1000, "train_seconds": 10.0, "fps": 100.0 * n,
         "eval": {"success_rate": success[-1], "n_episodes": 50}}))
    (run_dir / "command.txt").write_text(f"python -m sbagents.train --env {env_id} -f {folder}")


def _fake_training(pair: kuka_learning.Pair, folder: Path) -> list[tuple[str, str]]:
    suffix = f" {pair.name}" if pair.name else ""
    runs = [("ours", pair.ours_env)] + ([("panda-gym", pair.panda_env)] if pair.panda else [])
    for label, env_id in runs:
        _fake_run_dir(folder / label, env_id, [0.0, 0.5], folder)
    return [(label + suffix, str(folder / label)) for label, _ in runs]


@pytest.mark.parametrize("section", list(kuka_learning.TASKS))
def test_each_kuka_benchmark_trains_its_pairs(section: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``run`` (training stubbed) trains every default pair, writes one plot each and renders a section whose rows
    are the runs'; the recorded command hides the machine's paths."""
    monkeypatch.setattr(kuka_learning, "_train_both", lambda args, pair, conf, folder: _fake_training(pair, folder))
    task = kuka_learning.TASKS[section]
    results = json.loads(json.dumps(kuka_learning.run_task(section, [
        "--panda-python", "/venv/bin/python", "-f", str(tmp_path / "out"), "-n", "2000", "--plots", str(tmp_path)])))
    pairs = [key for key, pair in task.pairs.items() if pair.panda]
    assert [r["key"] for r in results["reports"]] == pairs and results["seeds"] == [0]
    assert results["commands"] == [f"python -m benchmarks run {section} --panda-python <panda-gym venv>/bin/python "
                                   "-f <output dir> -n 2000"]
    assert all((tmp_path / task.pairs[key].plot).exists() for key in pairs)
    text = kuka_learning.render(results)
    assert str(tmp_path) not in text and text.count("1 seed (seed 0) per run") == len(pairs)
    summary = [r for r in text.splitlines() if r.startswith("| ours") or r.startswith("| panda-gym")]
    assert len(summary) == 2 * len(pairs) and all("| 2000 | 50% | 50% | 50% (50) | 10 | 200 |" in r for r in summary)
    assert "| 2000 | 50 | 50 |" in text


def test_keep_stored_replaces_one_pair_and_keeps_the_notes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``--pairs dense --keep-stored``: the stored HER report and every note stay; the dense tables are the new
    run's."""
    monkeypatch.setattr(kuka_learning, "_train_both", lambda args, pair, conf, folder: _fake_training(pair, folder))
    stored = ROOT / "benchmarks" / "results" / "kuka_learning_random.json"
    old = json.loads(stored.read_text())
    results = kuka_learning.run_task("kuka-learning-random", [
        "--pairs", "dense", "--keep-stored", "--stored", str(stored), "--panda-python", "python",
        "-f", str(tmp_path), "--plots", str(tmp_path)])
    assert results["blocks"] == old["blocks"] and results["reports"][0] == old["reports"][0]
    assert [r["key"] for r in results["reports"]] == ["her", "dense"]
    assert [r["n_timesteps"] for r in results["reports"][1]["runs"]] == [2000, 2000]
    assert results["commands"][:-1] == old["commands"] and "--pairs dense --keep-stored" in results["commands"][-1]
