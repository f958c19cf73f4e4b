"""The ``trust-report`` benchmark: ``run`` (training and evaluation replaced by stand-ins) copies the run's plots
and CSVs and returns what ``markdown`` turns into the attack and fairness tables."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from benchmarks.suites import trust_report


def test_run_copies_the_plots_and_renders_both_tables(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def fake_train(spec: Any, output: Any, *args: Any) -> None:
        run_dir = Path(output.log_folder) / "ddpg" / "sbagents_SmartHome-v0_1"
        run_dir.mkdir(parents=True)
        for name in ("adversarial.png", "fairness.png", "adversarial.csv", "fairness.csv"):
            (run_dir / name).write_text(name)

    bucket = {"preferred_temp_low": 20.0, "preferred_temp_high": 22.0, "preferred_light_low": 50.0,
              "preferred_light_high": 60.0, "n": 2, "value": 0.5, "ci_low": 0.1, "ci_high": 0.9}
    report = {"adversarial": [{"attack": "none", "eps": 0.0, "mean_return": -20.0, "std_return": 2.0,
                               "success_rate": 1.0}],
              "fairness": {"keys": ["preferred_temp", "preferred_light"], "metric": "success_rate",
                           "buckets": [bucket], "worst": bucket, "gap": 0.0}}
    monkeypatch.setattr(trust_report, "train", fake_train)
    monkeypatch.setattr(trust_report, "evaluate", lambda ref, options: report)
    monkeypatch.setattr(trust_report, "RESULTS", tmp_path / "results")
    results = trust_report.run(["--episodes", "2"])
    assert sorted(p.name for p in (tmp_path / "results").iterdir()) == [
        "adversarial.csv", "adversarial.png", "fairness.csv", "fairness.png"]
    assert results["command"] == "python -m benchmarks run trust-report --episodes 2" and results["episodes"] == 2
    text = trust_report.markdown(results)
    assert "| none | 0 | -20.0 | 2.0 | 1.00 |" in text and "| 20-22 | 50-60 | 2 | 0.50 | 0.10-0.90 |" in text
    assert "-n 2 --attack" in text and "Worst bucket 0.50, max-min gap 0.00." in text
