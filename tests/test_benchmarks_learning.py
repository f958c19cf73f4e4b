"""The learning benchmarks of ``benchmarks/learning`` on tiny budgets: each ``run`` returns results that its
``render`` turns into a section with the expected rows (per seed, mean +- std, IQM [95% CI]); ``recorded-learning``
over the real results files and a made-up one. That BENCHMARKS.md holds what ``render`` makes of each real results
file is checked for every benchmark by tests/test_benchmarks_harness.py."""

from __future__ import annotations

import json
from functools import partial
from pathlib import Path
from typing import Any

import pytest
import torch
from cli_helpers import checked_cli

import benchmarks.stats
from benchmarks.harness import Benchmark, registry
from benchmarks.learning import learning, pettingzoo_learning, recorded, rllib_learning, treasure_hunt_learning
from benchmarks.learning.seed_table import iqm_note, stats_table
from benchmarks.report import RESULTS_DIR, load_results
from benchmarks.stats import format_iqm, format_mean_std

MINE = ("learning-smarthome", "learning-treasure-hunt-ppo", "recorded-learning", "treasure-hunt-learning",
        "pettingzoo-spread", "pettingzoo-spread-ctde", "pettingzoo-tag", "pettingzoo-pursuit", "pettingzoo-kaz",
        "rllib-simple_spread_v3", "rllib-treasure_hunt_v0")


@pytest.fixture(autouse=True)
def _one_thread() -> None:
    torch.set_num_threads(1)


@pytest.fixture
def quick_bootstrap(monkeypatch: pytest.MonkeyPatch) -> None:
    """Tiny runs: the statistics with 500 bootstrap resamples instead of 20,000 (about 2 s each)."""
    monkeypatch.setattr(benchmarks.stats, "seed_stats", partial(benchmarks.stats.seed_stats, reps=500))


def _bench(name: str) -> Benchmark:
    return registry()[name]


def _cells(section: str) -> list[list[str]]:
    """The cells of every Markdown table row in ``section`` (header and body rows; separator rows dropped)."""
    rows = [[c.strip() for c in line.strip().strip("|").split("|")] for line in section.splitlines()
            if line.startswith("|")]
    return [r for r in rows if not all(set(c) <= set("-: ") for c in r)]


def _stat_row(section: str, label: str) -> list[str]:
    """The statistics table's row of ``label`` (metric, per seed, mean +- std, IQM [95% CI])."""
    (row,) = [r for r in _cells(section) if r[0] == label and len(r) == 4]
    return row


def test_every_learning_benchmark_is_registered_with_its_results_file() -> None:
    benches = registry()
    assert set(MINE) <= set(benches)
    for name in MINE:
        bench = benches[name]
        assert bench.kind == "learning" and bench.results_path.exists(), name
        results = bench.load(bench.results_path)
        assert results["command"].startswith(f"python -m benchmarks run {name}"), name
        section = bench.render(results)
        assert section == bench.render(results) and "python -m benchmarks." not in section, name
        if name != "recorded-learning":
            assert "| metric | per seed | mean +- std | IQM [95% CI] |" in section and "rliable" in section, name


def test_stats_table_one_seed_shows_no_interval() -> None:
    stats = {"x": {"n": 1, "values": [2.5], "mean": 2.5, "std": 0.0, "iqm": 2.5, "iqm_ci": [2.5, 2.5]}}
    lines = stats_table(stats, [("x", "x", ".1f"), ("absent", "y", ".1f")])
    assert lines[2:] == ["| x | 2.5 | - | - |"]
    assert iqm_note(1).startswith("1 seed") and "3 seeds" in iqm_note(3)


@pytest.mark.parametrize(("name", "algos"), [("learning-smarthome", ["sac", "ddpg"]),
                                             ("learning-treasure-hunt-ppo", ["ppo"])])
def test_learning_tiny(name: str, algos: list[str], quick_bootstrap: None) -> None:
    bench = _bench(name)
    options = ["--algo", *algos, "--seeds", "0", "1", "-n", "200", "--episodes", "2", "--eval-freq", "-1"]
    results = bench.run(options)
    assert json.loads(json.dumps(results)) == results  # JSON-able
    assert results["algos"] == algos and results["command"] == f"python -m benchmarks run {name} {' '.join(options)}"
    section = bench.render(results)
    runs = [r for r in _cells(section) if r[0] in algos]
    assert [(r[0], r[2]) for r in runs] == [(a, s) for a in algos for s in ("0", "1")]
    for algo in algos:
        stats = results["stats"][algo]["mean_return"]
        assert stats["n"] == 2 and stats["values"] == [r["eval"]["mean_return"] for r in results["runs"][algo]]
        assert _stat_row(section, f"{algo}: mean return")[2:] == [format_mean_std(stats, ".1f"),
                                                                  format_iqm(stats, ".1f")]
    assert "Machine:" in section and "2 seeds" in section


def test_treasure_hunt_learning_tiny(quick_bootstrap: None) -> None:
    bench = _bench("treasure-hunt-learning")
    results = bench.run(["--seeds", "0", "-n", "2048", "--n-eval", "3", "--via", "direct"])
    (run,) = results["runs"]
    assert run["via"] == "direct" and results["n_eval"] == 3 and results["target_met"] is False
    section = bench.render(results)
    assert [r[:2] for r in _cells(section)[1:2]] == [["0", "direct"]]
    assert _stat_row(section, "treasures/episode") == ["treasures/episode", f"{run['treasures']:.2f}", "-", "-"]
    assert "evaluated on 3 episodes" in section and "1 seed" in section and "Target not met" in section



@pytest.mark.parametrize("task", [pytest.param(t, marks=pytest.mark.slow) if t == "pursuit" else t
                                  for t in sorted(pettingzoo_learning.TASKS)])  # pursuit: 500-step episodes
def test_pettingzoo_tiny(task: str, tmp_path: Path, quick_bootstrap: None, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every task on 64 steps of a shrunk config and 1-2 episodes, the CLI commands run in-process (the same argv
    through ``sbagents.train.main`` / ``sbagents.evaluate.main``; an interpreter start costs ~10 s on 2 busy cores)."""
    monkeypatch.setattr(pettingzoo_learning, "cli", checked_cli)
    bench = _bench(f"pettingzoo-{task}")
    png = tmp_path / "curve.png"
    episodes = "1" if task == "pursuit" else "2"  # 500 steps an episode
    results = bench.run(["--seeds", "0", "-n", "64", "--eval-episodes", episodes, "--plot", str(png), "--params",
                         "n_envs:2", "n_steps:16", "batch_size:32", "n_epochs:1"])
    assert png.stat().st_size > 0 and results["eval_episodes"] == int(episodes) and results["seeds"] == [0]
    section = bench.render(results)
    assert _cells(section)[1][0] == "0" and f"evaluated on {episodes} episodes" in section
    assert "-params n_envs:2 n_steps:16 batch_size:32 n_epochs:1" in section
    assert _stat_row(section, "team return")[1] == f"{results['runs'][0]['mean_return']:.2f}"
    assert "random play" in section
    assert results["command"].startswith(f"python -m benchmarks run pettingzoo-{task} --seeds 0 -n 64")


def test_pettingzoo_add_and_replot(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    saved = load_results(RESULTS_DIR / "pettingzoo_kaz.json")
    new = {**saved["runs"][0], "seed": 7}
    monkeypatch.setattr(pettingzoo_learning, "run_one", lambda *a: new)
    monkeypatch.setattr(pettingzoo_learning, "baselines", lambda task: {})
    monkeypatch.setattr(pettingzoo_learning, "metric_stats", lambda values: {})
    results = pettingzoo_learning.run_task("kaz", ["--seeds", "7", "--add", "--plot", ""])
    assert results["seeds"] == [0, 1, 2, 7] and [r["seed"] for r in results["runs"]] == [0, 1, 2, 7]
    png = tmp_path / "kaz.png"
    assert pettingzoo_learning.run_task("kaz", ["--replot", "--plot", str(png)]) == saved and png.exists()


def _rllib_result(seeds: list[int], checkpoint: bool) -> dict[str, Any]:
    runs = [{"seed": s, "env_steps": 1000, "train_seconds": 10.0 + s, "fps": 100.0, "team_return": -30.0 + s,
             "treasures_per_episode": None, "n_eval_episodes": 5, "load_start": 1.0, "load": 1.5,
             **({"checkpoint": {"within_seconds": 300.0, "env_steps": None, "train_seconds": None,
                                "team_return": None}} if checkpoint else {})} for s in seeds]
    return {"env": "mpe2.simple_spread_v3", "params": {}, "eval_seed": None, "runs": runs,
            "command": "python -m benchmarks run rllib-simple_spread_v3 --seeds " + " ".join(map(str, seeds)),
            "stats": {"team_return": {"n": len(seeds), "values": [r["team_return"] for r in runs], "mean": -30.0,
                                      "std": 0.0, "iqm": -30.0, "iqm_ci": [-30.0, -29.0]}}}


def test_rllib_render_without_ray() -> None:
    section = rllib_learning.render(_rllib_result([0], checkpoint=True))
    assert _cells(section)[1] == ["0", "1,000", "10", "100", "-30.00", "-", "-", "-", "1.0 / 1.5"]
    assert _stat_row(section, "team return") == ["team return", "-30.00", "-", "-"] and "1 seed" in section
    assert rllib_learning.run_values(_rllib_result([0, 1], checkpoint=True)["runs"]) == {
        "team_return": [-30.0, -29.0], "train_seconds": [10.0, 11.0]}  # no checkpoint saved: no statistics


def test_rllib_tiny(quick_bootstrap: None) -> None:
    from sbagents.rllib import ray_available

    if not ray_available():
        pytest.skip("needs Ray RLlib (pip install -e '.[test,distributed]')")
    pytest.importorskip("rliable", reason="the statistics need rliable (pip install -e '.[bench]')")
    bench = _bench("rllib-treasure_hunt_v0")
    results = bench.run(["--seeds", "0", "-n", "1000", "--n-eval", "2", "--num-env-runners", "1", "--params",
                         "train_batch_size_per_learner:1000", "minibatch_size:256", "num_envs_per_env_runner:2"])
    (run,) = results["runs"]
    assert run["env_steps"] >= 1000 and not run["interrupted"] and "run_dir" not in run
    section = bench.render(results)
    assert _cells(section)[1][0] == "0" and _stat_row(section, "treasures/episode")[2:] == ["-", "-"]


def test_recorded_table_from_real_results(tmp_path: Path) -> None:
    bench = _bench("recorded-learning")
    results = bench.run([])
    rows = results["rows"]
    by_file: dict[str, list[dict[str, Any]]] = {}
    for row in rows:
        by_file.setdefault(row["file"], []).append(row)
    learning_files = sorted(p.name for p in RESULTS_DIR.glob("learning_*.json"))
    assert learning_files and set(learning_files) | {"treasure_hunt_learning.json"} == set(by_file)
    section = bench.render(results)
    for name in learning_files:  # the key metric per seed, from the file itself
        data = load_results(RESULTS_DIR / name)
        assert [r["algo"] for r in by_file[name]] == sorted(data["algos"])
        for row in by_file[name]:
            runs = data["runs"][row["algo"]]
            assert row["seeds"] == " ".join(str(s) for s in sorted(r["seed"] for r in runs))
            assert row["train_s"].startswith(f"{min(r['train_seconds'] for r in runs):.1f}")
            values = [learning.key_metric(data["env"], r) for r in runs]
            fmt = ".1%" if data["env"] == "sbagents/SmartHome-v0" else ".2f"
            assert row["per_seed"] == " / ".join(format(v, fmt) for v in values)
            assert f"`{data['command']}`" in section and row["date"] == data["date"]
    (th,) = by_file["treasure_hunt_learning.json"]
    saved = load_results(RESULTS_DIR / "treasure_hunt_learning.json")
    assert th["per_seed"] == " / ".join(f"{r['treasures']:.2f}" for r in saved["runs"])
    assert th["iqm_ci"] == format_iqm(saved["stats"]["treasures"])
    assert f"`{saved['command']}`" in section
    assert len(_cells(section)) == len(rows) + 1  # header + one row per file and algorithm
    assert recorded.render(results) == recorded.render(json.loads(json.dumps(results)))


def test_recorded_generic_env(tmp_path: Path, quick_bootstrap: None) -> None:
    def run(seed: int, mean_return: float) -> dict[str, Any]:
        return {"algo": "a2c", "env": "CartPole-v1", "seed": seed, "n_timesteps": 1000, "train_seconds": 2.0,
                "eval": {"mean_return": mean_return, "success_rate": None, "metrics": {}}, "load_before": 1.0}

    data = {"env": "CartPole-v1", "algos": ["a2c"], "runs": {"a2c": [run(3, 120.5), run(1, 80.25)]},
            "command": "python -m benchmarks run learning-cartpole --seeds 3 1"}
    (tmp_path / "learning_CartPole-v1.json").write_text(json.dumps(data))
    results = recorded.run(["--results-dir", str(tmp_path)])
    (row,) = results["rows"]
    assert (row["metric"], row["per_seed"], row["success"], row["seeds"], row["date"]) == (
        "mean return", "120.50 / 80.25", "-", "1 3", "-")
    assert row["mean_std"] == "100.38 +- 28.46"
    assert "--seeds 3 1" in recorded.render(results)
    assert recorded.render({"command": "c", "rows": []}).endswith("| (no results files) | | | | | | | | | | | |")


def test_learning_render_of_legacy_metric_name() -> None:
    """``treasures_per_episode`` (the metric's name before ``treasures_collected``) still counts as the key."""
    run = {"eval": {"mean_return": 1.0, "metrics": {"treasures_per_episode": 4.5}}}
    assert learning.key_metric("treasure_hunt_v0", run) == 4.5 and learning.key_metric("CartPole-v1", run) is None


def test_treasure_hunt_render_with_params() -> None:
    saved = load_results(RESULTS_DIR / "treasure_hunt_learning.json")
    section = treasure_hunt_learning.render({**saved, "params": {"n_envs": 16}})
    assert 'with overrides `{"n_envs": 16}`' in section
