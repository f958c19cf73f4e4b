"""The trust flags of train/evaluate end to end (the callbacks themselves are tested in test_callbacks_*)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

from cli_helpers import cli, last_json

ENV = "sbagents/SmartHome-v0"


def test_train_with_every_trust_flag_then_evaluate(tmp_path: Path) -> None:
    # plumbing, not learning: 600 steps, evaluated (under attack, by fairness bucket) twice
    result = cli("train", "--algo", "ddpg", "--env", ENV, "-n", "600", "-f", str(tmp_path), "--seed", "0",
                 "--verbose", "0", "--final-eval-episodes", "1", "--eval-freq", "300", "--eval-episodes", "2",
                 "--transparency-log", "--safety", "--adversarial-eval", "gaussian:0.1 pgd:0.1",
                 "--fairness", "preferred_temp", "--bins", "2")
    assert result.returncode == 0, result.stderr
    run_dir = tmp_path / "ddpg" / "sbagents_SmartHome-v0_1"
    with open(run_dir / "transparency.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 600
    assert list(rows[0])[:8] == ["env", "episode", "step", "Temperature", "Light_Level", "Time", "Preferred_Temp",
                                 "Preferred_Light"]
    safety = json.loads((run_dir / "safety.json").read_text())
    assert safety["total_steps"] == 600 and safety["total_violations"] == 0
    for name in ("adversarial.csv", "adversarial.png", "fairness.csv", "fairness.png"):
        assert (run_dir / name).stat().st_size > 0, name
    end = result.stdout.splitlines()[-3:]  # the trust results close the summary
    assert end[0] == "safety: 0 violation steps in 600 steps (0 per 1,000), mean episode cost 0"
    with open(run_dir / "adversarial.csv") as handle:
        last = [r for r in csv.DictReader(handle) if r["timesteps"] == "600"]
    parts = [f"{'clean' if r['attack'] == 'none' else r['attack'] + '_' + r['eps']} {float(r['mean_return']):.2f} "
             f"(success {float(r['success_rate']):.2f})" for r in last]
    assert end[1] == "mean return under attack: " + ", ".join(parts)
    assert end[2].startswith("fairness (success_rate by preferred_temp): worst bucket ")

    report = last_json(cli("evaluate", "--algo", "ddpg", "--env", ENV, "-f", str(tmp_path), "-n", "4", "--json",
                           "--attack", "uniform:0.1", "--fairness", "preferred_temp,preferred_light").stdout)
    assert [r["label"] for r in report["adversarial"]] == ["none_0", "uniform_0.1"]
    assert sum(b["n"] for b in report["fairness"]["buckets"]) == 4


def test_book_header_for_smart_home(tmp_path: Path) -> None:
    log = tmp_path / "decisions.csv"
    result = cli("train", "--algo", "td3", "--env", ENV, "-n", "300", "-f", str(tmp_path), "--seed", "0",
                 "--verbose", "0", "--final-eval-episodes", "1", "--transparency-log", str(log),
                 "--transparency-format", "book")
    assert result.returncode == 0, result.stderr
    lines = log.read_text().splitlines()
    assert lines[0] == ("Episode,Step,Temperature,Light_Level,Time,Preferred_Temp,Preferred_Light,"
                        "Action_Temp,Action_Light,Reward")
    assert len(lines) == 301


def test_bad_trust_input_is_one_line(tmp_path: Path) -> None:
    result = cli("train", "--algo", "ppo", "--adversarial-eval", "laser:0.1", "-f", str(tmp_path))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.startswith("python -m sbagents.train: error: --adversarial-eval:")
    assert result.stderr.count("\n") == 1 and not (tmp_path / "ppo").exists()
