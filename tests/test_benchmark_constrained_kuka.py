"""The constrained Kuka benchmark's results file: runs of parallel processes are merged, stored runs are not redone,
and a change of budget or config starts afresh (training replaced by a stub: the file logic is under test)."""

from __future__ import annotations

import json
from functools import partial
from pathlib import Path
from typing import Any

import pytest

import benchmarks.stats
from benchmarks.learning import constrained_kuka
from benchmarks.report import save_results
from benchmarks.stats import seed_stats


@pytest.fixture(autouse=True)
def _short_bootstrap(monkeypatch: pytest.MonkeyPatch) -> None:
    """200 bootstrap resamples instead of 20,000 (2 s per metric): these tests check the file logic and the rows."""
    monkeypatch.setattr(benchmarks.stats, "seed_stats", partial(seed_stats, reps=200))


def _run(argv: list[str], results: Path) -> str:
    """What ``python -m benchmarks run constrained-kuka --stored RESULTS ...`` does with the results (saved to the
    file the next run reads); the section."""
    outcome = constrained_kuka.run([*argv, "--stored", str(results)])
    save_results(outcome, results)
    return constrained_kuka.markdown(outcome)


def _fake_run(calls: list[tuple[str, int, int]]) -> Any:
    def run(method: str, seed: int, n_timesteps: int, *args: Any) -> dict[str, Any]:
        calls.append((method, seed, n_timesteps))
        return {
            "method": method,
            "seed": seed,
            "n_timesteps": n_timesteps,
            "train_s": 600.0,
            "success": 0.5 + seed / 10,
            "cost": 0.25,
            "return": 10.0,
            "train_cost_last100": 0.5,
            "train_success_last100": 0.4,
            "multiplier": 0.1 if method == "sac-lagrangian" else None,
            "history": [],
        }

    return run


def test_results_of_two_processes_merge_and_stored_runs_are_kept(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[tuple[str, int, int]] = []
    monkeypatch.setattr(constrained_kuka, "run_one", _fake_run(calls))
    results = tmp_path / "results.json"
    common = ["-n", "100", "--logs", str(tmp_path)]
    _run([*common, "--methods", "sac", "--seeds", "0", "1"], results)
    text = _run([*common, "--methods", "sac-lagrangian", "--seeds", "0"], results)
    data = json.loads(results.read_text())
    assert {(r["method"], r["seed"]) for r in data["runs"]} == {("sac", 0), ("sac", 1), ("sac-lagrangian", 0)}
    assert data["args"]["seeds"] == [0, 1]
    assert data["args"]["methods"] == ["sac-lagrangian", "sac"]
    assert len(data["commands"]) == 2
    assert not any("--logs" in command or "--stored" in command for command in data["commands"])  # folders
    assert "logs" not in data["args"] and "stored" not in data["args"]
    assert data["commands"][0] == "python -m benchmarks run constrained-kuka -n 100 --methods sac --seeds 0 1"
    assert "| sac-lagrangian (0) | 100 | 0.50 | 0.25 |" in text
    assert "| **sac mean** |  | 0.55 |" in text
    assert "Not finished in this session: sac-lagrangian (1)." in text
    assert "training time summed over the runs 30 min" in text

    calls.clear()
    _run([*common, "--methods", "sac", "--seeds", "0", "1"], results)
    assert calls == []  # both stored: nothing retrained

    _run([*common[:1], "200", *common[2:], "--methods", "sac", "--seeds", "0"], results)
    assert calls == [("sac", 0, 200)]  # another budget: the stored runs do not count
    assert [r["n_timesteps"] for r in json.loads(results.read_text())["runs"]] == [200]


def test_a_changed_config_entry_discards_stored_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[tuple[str, int, int]] = []
    monkeypatch.setattr(constrained_kuka, "run_one", _fake_run(calls))
    results = tmp_path / "results.json"
    common = ["-n", "100", "--methods", "sac", "--seeds", "0"]
    _run(common, results)
    stored = json.loads(results.read_text())
    stored["config"]["env_kwargs"]["noise_level"] = 0.05
    results.write_text(json.dumps(stored))
    _run(common, results)
    assert calls == [("sac", 0, 100), ("sac", 0, 100)]


def test_tiny_run_trains_evaluates_and_renders(tmp_path: Path) -> None:
    """A real run on a tiny budget (no stub): SAC-Lagrangian trains, checkpoints nothing yet, is evaluated greedily and
    makes a section row; one seed shows no interval."""
    text = _run(["-n", "300", "--episodes", "1", "--methods", "sac-lagrangian", "--logs", str(tmp_path)],
                tmp_path / "results.json")
    run = json.loads((tmp_path / "results.json").read_text())["runs"][0]
    assert run["method"] == "sac-lagrangian" and run["n_timesteps"] == 300 and run["multiplier"] is not None
    assert "| sac-lagrangian (0) | 300 |" in text and "| sac-lagrangian | EpCost | 1 |" in text
