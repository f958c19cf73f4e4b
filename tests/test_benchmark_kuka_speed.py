"""The Kuka speed benchmark pairs each env with a timing of its panda-gym reference in the same round, reports the
median and range of the per-round ratios, and writes its section (panda-gym replaced by a cheap stand-in env)."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import gymnasium as gym
import pytest

from benchmarks.__main__ import main as bench_main
from benchmarks.speed import kuka_speed


def test_per_round_ratios_and_section(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    timings = iter([300.0, 100.0, 100.0, 400.0, 260.0, 200.0, 200.0, 100.0])  # (env, ref) pairs, order alternating
    monkeypatch.setattr(kuka_speed, "steps_per_second", lambda env, steps, seed=0: (next(timings), 1))
    specs: list[kuka_speed.Spec] = [
        ("push", lambda: gym.make("CartPole-v1"), kuka_speed.PUSH_REFERENCE),
        ("pick", lambda: gym.make("CartPole-v1"), kuka_speed.PICK_REFERENCE),
    ]
    cartpole = functools.partial(gym.make, "CartPole-v1")
    references = {ref: cartpole for ref in (kuka_speed.PUSH_REFERENCE, kuka_speed.PICK_REFERENCE)}
    rates, ratios = kuka_speed.measure(specs, references, steps=10, rounds=2)
    # round 0: push then ref (300/100), pick's pair reversed (ref 100 first, then pick 400)
    # round 1: push's pair reversed (ref 260 first, then push 200), pick then ref (200/100)
    assert ratios == {"push": [3.0, 200.0 / 260.0], "pick": [4.0, 2.0]}
    assert rates[kuka_speed.PUSH_REFERENCE] == [100.0, 260.0] and rates["pick"] == [400.0, 200.0]
    rows = kuka_speed.summarize(specs, rates, ratios)
    assert rows[1]["ratio"] == pytest.approx(3.0) and (rows[1]["ratio_min"], rows[1]["ratio_max"]) == (2.0, 4.0)
    assert [r["env"] for r in rows[2:]] == ["panda-gym `PandaPush-v3`", "panda-gym `PandaPickAndPlace-v3`"]
    results = {"command": "python -m benchmarks run kuka-speed --steps 10", "cpu": "x", "steps": 10, "rounds": 2,
               "load_average": 0.5, "rows": rows}
    text = kuka_speed.markdown(results)
    assert "| pick | 300 | 3.00x | 2.00-4.00x | `PandaPickAndPlace-v3` |" in text
    assert "`<panda-gym venv>/bin/python -m benchmarks run kuka-speed --steps 10`" in text


def test_main_without_panda_gym_writes_rates_and_no_ratios(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(__import__("sys").modules, "panda_gym", None)  # import fails as when it is not installed
    monkeypatch.setattr(
        kuka_speed, "kuka_specs", lambda: [("joints push", kuka_speed.PickAndPlaceEnv, kuka_speed.PUSH_REFERENCE)]
    )
    out, raw = tmp_path / "BENCH.md", tmp_path / "speed.json"
    assert bench_main(["run", "--output", str(out), "--results", str(raw), "kuka-speed", "--steps", "20",
                       "--rounds", "2"]) == 0
    data = json.loads(raw.read_text())
    assert len(data["rates"]["joints push"]) == 2 and all(r > 0 for r in data["rates"]["joints push"])
    assert data["ratios"] == {"joints push": []}
    section = out.read_text()
    assert "<!-- kuka-speed:start -->" in section and "`PandaPush-v3` (not installed)" in section
    assert str(tmp_path) not in section  # the output paths are not part of the recorded command
