"""``pong-cpu`` on a tiny budget: PQN trained for 40 s of training time on Pong, stopped with Ctrl-C (its model
saved), every checkpoint scored by greedy games; a run whose session ended (no ``summary.json``) goes on from its
latest checkpoint, and its parts' training seconds add up."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("ale_py", reason="Pong needs ale-py: pip install -e '.[test]'")


@pytest.mark.slow  # two short Pong trainings and their greedy games (~2 min here)
def test_pong_cpu_quick_run_scores_checkpoints_and_continues_a_stopped_run(tmp_path: Path) -> None:
    from benchmarks.learning.pong_cpu import render, run

    results = run(["-f", str(tmp_path), "--algos", "pqn", "--quick"])
    (row,) = results["rows"]
    assert row["algo"] == "pqn" and row["parts"] == 1 and row["curve"][-1]["steps"] >= 2000
    assert all(-21 <= c["score"] <= 21 for c in row["curve"]) and 0 < row["final"]["train_s"] <= 40 + 60
    assert "| pqn | 0 | 40 |" in render(results)
    logs = tmp_path / "pqn" / "seed0"
    (first,) = logs.glob("pqn/PongNoFrameskip-v4_*")
    (first / "summary.json").unlink()  # as if the session had ended mid-run, after its first checkpoint
    for later in sorted(first.glob("rl_model_*_steps.zip"), key=lambda p: int(p.stem.split("_")[2]))[1:]:
        later.unlink()
    again = run(["-f", str(tmp_path), "--algos", "pqn", "--quick"])["rows"][0]
    assert again["parts"] == 2
    words = sorted(logs.rglob("command.txt"))[-1].read_text().split()
    assert words[words.index("-i") + 1].endswith("_steps.zip")
    scores = json.loads((logs / "scores.json").read_text())
    assert {c["score"] for c in again["curve"]} <= {v["score"] for v in scores.values()}  # scored once, kept
    seconds = [c["train_s"] for c in again["curve"]]
    assert seconds == sorted(seconds) and again["curve"][-1]["steps"] > 2000  # the parts' seconds add up
