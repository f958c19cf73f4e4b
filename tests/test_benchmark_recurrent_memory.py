"""The recurrent-memory benchmark on a tiny budget: both algorithms train and evaluate in child processes, rows are
appended as runs end (a second call resumes and trains nothing), and the section renders."""

from __future__ import annotations

import json
from pathlib import Path

from benchmarks.learning.recurrent_memory import render, run


def test_a_tiny_measurement_resumes_and_renders(tmp_path: Path) -> None:
    argv = ["--quick", "--n-timesteps", "256", "--envs", "sbagents/CartPoleNoVel-v1", "--work", str(tmp_path)]
    results = run(argv)
    rows = results["runs"]
    assert [(r["algo"], r["seed"]) for r in rows] == [("ppo_lstm", 0), ("ppo", 0)]
    assert all(r["return"] > 0 and r["episodes"] == 20 and r["best_return"] > 0 for r in rows)
    logged = [json.loads(line) for line in (tmp_path / "runs.jsonl").read_text().splitlines()]
    assert len(logged) == 2
    again = run(argv)  # everything is in runs.jsonl: nothing is trained again
    assert again["runs"] == rows and len((tmp_path / "runs.jsonl").read_text().splitlines()) == 2
    section = render(results)
    assert section.startswith("## Memory: RecurrentPPO") and "| sbagents/CartPoleNoVel-v1 |" in section
    assert "at RL Zoo's level (>= 450)" in section
