"""The constrained Kuka benchmark's results file: runs of parallel processes are merged, stored runs are not redone,
and a change of budget or config starts afresh (training replaced by a stub: the file logic is under test)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from benchmarks import constrained_kuka


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
    monkeypatch.setattr(constrained_kuka, "run", _fake_run(calls))
    results, section = tmp_path / "results.json", tmp_path / "BENCH.md"
    common = ["-n", "100", "--json", str(results), "--output", str(section), "--logs", str(tmp_path)]
    constrained_kuka.main([*common, "--methods", "sac", "--seeds", "0", "1"])
    constrained_kuka.main([*common, "--methods", "sac-lagrangian", "--seeds", "0"])
    data = json.loads(results.read_text())
    assert {(r["method"], r["seed"]) for r in data["runs"]} == {("sac", 0), ("sac", 1), ("sac-lagrangian", 0)}
    assert data["args"]["seeds"] == [0, 1]
    assert data["args"]["methods"] == ["sac-lagrangian", "sac"]
    assert len(data["commands"]) == 2
    assert not any("--logs" in command for command in data["commands"]) and "logs" not in data["args"]  # a folder
    text = section.read_text()
    assert "| sac-lagrangian (0) | 100 | 0.50 | 0.25 |" in text
    assert "| **sac mean** |  | 0.55 |" in text
    assert "Not finished in this session: sac-lagrangian (1)." in text
    assert "training time summed over the runs 30 min" in text

    calls.clear()
    constrained_kuka.main([*common, "--methods", "sac", "--seeds", "0", "1"])
    assert calls == []  # both stored: nothing retrained

    constrained_kuka.main([*common[:1], "200", *common[2:], "--methods", "sac", "--seeds", "0"])
    assert calls == [("sac", 0, 200)]  # another budget: the stored runs do not count
    assert [r["n_timesteps"] for r in json.loads(results.read_text())["runs"]] == [200]


def test_a_changed_config_entry_discards_stored_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[tuple[str, int, int]] = []
    monkeypatch.setattr(constrained_kuka, "run", _fake_run(calls))
    results = tmp_path / "results.json"
    common = ["-n", "100", "--json", str(results), "--output", "", "--methods", "sac", "--seeds", "0"]
    constrained_kuka.main(common)
    stored = json.loads(results.read_text())
    stored["config"]["env_kwargs"]["noise_level"] = 0.05
    results.write_text(json.dumps(stored))
    constrained_kuka.main(common)
    assert calls == [("sac", 0, 100), ("sac", 0, 100)]
