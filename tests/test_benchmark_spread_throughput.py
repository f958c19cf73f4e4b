"""``spread-throughput`` on tiny step counts: each measurement returns a positive rate, the rounds are interleaved with
their median kept, BenchMARL's training rates come from a ``benchmarl-spread`` results file, and the section renders
from a results dict alone."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from benchmarks.speed import spread_throughput as st


def test_env_rates_are_positive() -> None:
    assert st.batched_rate(4, 30) > 0
    assert st.mpe2_loop_rate(60) > 0


def test_ppo_collection_is_faster_than_the_whole_learn() -> None:
    rates = st.ppo_collection_rate(1)  # two rollouts of the entry's n_envs x n_steps
    assert rates["collection"] > rates["learn"] > 0


def test_median_rounds_interleaves() -> None:
    calls: list[str] = []
    values = iter([1.0, 10.0, 3.0, 30.0, 2.0, 20.0])

    def fn(key: str) -> float:
        calls.append(key)
        return next(values)

    out = st.median_rounds({"a": lambda: fn("a"), "b": lambda: fn("b")}, 3)
    assert calls == ["a", "b"] * 3
    assert out["a"] == {"median": 2.0, "rounds": [1.0, 3.0, 2.0]} and out["b"]["median"] == 20.0


def test_benchmarl_training_rates_from_results(tmp_path: Path) -> None:
    path = tmp_path / "benchmarl_spread.json"
    assert st.benchmarl_training_rates(path) == []
    run = {"algo": "mappo", "seed": 0, "load_start": [5.0], "load_end": [6.0],
           "total": {"agent_steps": 126_000, "train_s": 900.0, "collection_s": 360.0}}
    path.write_text(json.dumps({"benchmarl": [run]}))
    (row,) = st.benchmarl_training_rates(path)
    assert row["overall"] == 140.0 and row["collection"] == 350.0


def _result(venv: bool) -> dict[str, Any]:
    rates = {k: {"median": v, "rounds": [v, v]} for k, v in
             {"batched_16": 90_000.0, "batched_64": 200_000.0, "mpe2_loop": 6_000.0, "ppo_collection": 40_000.0,
              "ppo_learn": 12_000.0, "ppo_cli": 11_000.0}.items()}
    if venv:
        rates["benchmarl_collection"] = {"median": 600.0, "rounds": [600.0, 590.0]}
    return {"rates": rates, "rounds": 2, "load_start": [1.0], "load_end": [1.5], "benchmarl_venv": venv,
            "benchmarl_training": [{"algo": "ippo", "seed": 0, "agent_steps": 90_000, "overall": 150.0,
                                    "collection": 400.0, "load": [5.0, 6.0]}],
            "settings": {"env_steps": 2000}, "machine": {"cpu": "CPU", "cores": 2},
            "command": "python -m benchmarks run spread-throughput"}


def test_render() -> None:
    text = st.render(_result(True))
    assert "| (a) our batched VecEnv, 64 teams, random actions | 200,000 | 33.33 | 200,000 / 200,000 |" in text
    assert "| (d) BenchMARL collection (MAPPO policy, 10 serial envs) | 600 | 0.10 | 600 / 590 |" in text
    assert "BenchMARL IPPO training overall" in text and "absent" not in text
    assert "absent" in st.render(_result(False))


def test_bad_options_are_one_line() -> None:
    with pytest.raises(SystemExit, match="positive"):
        st.run(["--rounds", "0"])
