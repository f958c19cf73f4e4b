"""Benchmarks on tiny budgets through ``python -m benchmarks run NAME``, into a tmp Markdown and results file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from cli_helpers import OTHER_SECTION, section_text

from benchmarks.__main__ import main as bench_main
from benchmarks.speed import batched, callback_overhead, export_latency

ROOT = Path(__file__).resolve().parents[1]

RESULTS = ROOT / "benchmarks" / "results"


@pytest.fixture(autouse=True)
def _one_thread() -> None:
    torch.set_num_threads(1)



def _cells(section: str) -> list[list[str]]:
    """The cells of every Markdown table row in ``section`` (header and body rows; separator rows dropped)."""
    rows = [[c.strip() for c in line.strip().strip("|").split("|")] for line in section.splitlines()
            if line.startswith("|")]
    return [r for r in rows if not all(set(c) <= set("-: ") for c in r)]


def _md_file(tmp_path: Path) -> Path:
    path = tmp_path / "BENCH.md"
    path.write_text("# Benchmarks\n\n" + OTHER_SECTION)
    return path


def test_callback_overhead_tiny(tmp_path: Path) -> None:
    md, raw = _md_file(tmp_path), tmp_path / "cb.json"
    assert bench_main(["run", "--output", str(md), "--results", str(raw), "callback-overhead",
                       "--timesteps", "1024", "--repeats", "1", "--envs", "GridWorld"]) == 0
    results = json.loads(raw.read_text())
    grid = results["results"]["GridWorld"]
    assert list(grid) == list(callback_overhead.VARIANTS)
    assert grid["none"]["overhead_pct"] == 0.0
    assert all(len(r["samples"]) == 1 for r in grid.values())  # one repeat asked, one sample each
    for row in grid.values():  # the overhead is the fps drop against the no-callback run of the same round
        assert row["overhead_pct"] == pytest.approx(100 * (1 - row["fps_cpu"] / grid["none"]["fps_cpu"]), abs=0.1)
    assert results["timesteps"] == 1024
    section = section_text(md.read_text(), "callback-overhead")
    assert "`python -m benchmarks run callback-overhead --timesteps 1024 --repeats 1 --envs GridWorld`" in section
    by_variant = {r[1]: r for r in _cells(section)[1:] if r[0] == "GridWorld"}
    assert set(by_variant) == set(grid)
    for name, row in grid.items():  # the table shows the measured numbers
        assert f"{row['fps_cpu']:,.0f}" in by_variant[name]
    with pytest.raises(ValueError, match="unknown"):
        callback_overhead.run(envs=["Pong"])


def test_export_latency_tiny(tmp_path: Path) -> None:
    md, raw = _md_file(tmp_path), tmp_path / "ex.json"
    argv = ["--train-steps", "0", "--latency-n", "30", "--n-observations", "50"]
    assert bench_main(["run", "--output", str(md), "--results", str(raw), "export-latency", *argv]) == 0
    results = json.loads(raw.read_text())
    assert results["parity"]["onnx"] < 1e-4
    assert 0 < results["files"]["onnx_int8"] < results["files"]["onnx"]
    lat = results["latency"]
    assert set(lat) == {"sb3_predict", "onnx", "onnx_int8"}
    assert results["action_bounds"] == [[-1.0, 1.0], [-10.0, 10.0]]
    section = section_text(md.read_text(), "export-latency")
    cells = [c for row in _cells(section) for c in row]
    assert f"{results['files']['onnx']:,} B" in cells and f"{results['files']['onnx_int8']:,} B" in cells
    assert all(f"{row['p50_us']:.1f} us" in cells for row in lat.values())  # the table shows the measured numbers
    assert f"`python -m benchmarks run export-latency {' '.join(argv)}`" in section
    assert "untrained weights" in section and OTHER_SECTION in md.read_text()


def test_quick_options_replace_the_old_suite_runner(monkeypatch: pytest.MonkeyPatch) -> None:
    """``--quick`` of speed, callback-overhead and export-latency (the old ``python -m benchmarks --quick``) sets
    their short budgets and is part of the recorded command."""
    calls: dict[str, Any] = {}
    monkeypatch.setattr(batched, "measure", lambda **kw: calls.setdefault("speed", kw) and {})
    monkeypatch.setattr(callback_overhead, "run", lambda *a: calls.setdefault("callbacks", a) and {})
    monkeypatch.setattr(export_latency, "run", lambda *a: calls.setdefault("export", a) and {})
    assert batched.run(["--quick"])["command"] == "python -m benchmarks run speed --quick"
    assert calls["speed"] == {"rounds": 3, "quick": True, "env_ids": batched.ENV_IDS}
    assert callback_overhead.run_cli(["--quick"])["command"] == "python -m benchmarks run callback-overhead --quick"
    assert calls["callbacks"][:2] == (4096, 1)
    assert export_latency.run_cli(["--quick", "--seed", "3"])["command"].endswith("export-latency --quick --seed 3")
    assert calls["export"] == (0, 200, 200, 3)


def test_speed_markdown_has_ratios() -> None:
    speed = batched
    kwargs_64 = speed.ppo_kwargs("sbagents/GridWorld-v0", 64)
    kwargs_8 = speed.ppo_kwargs("sbagents/GridWorld-v0", 8)
    assert kwargs_64["batch_size"] == 8 * kwargs_8["batch_size"]  # same minibatches per rollout
    results = {
        "machine": {"cpu": "x", "cores": 2, "python": "3.11", "numpy": "2", "torch": "2", "stable_baselines3": "2",
                    "date": "d", "load_before": [1.0], "load_after": [1.0]},
        "command": "python -m benchmarks run speed",
        "envs": {"sbagents/GridWorld-v0": {
            "config_n_envs": 8, "ppo_batch_size": {"8": 256, "64": 2048},
            "steps_per_s": {"single": 4e5, "reference": 2.5e5, "batched": 7.5e6, "noop": 1.5e7},
            "ppo_fps": {"reference_8": 2e4, "batched_8": 2.2e4, "noop_8": 2.4e4, "reference_64": 5e4,
                        "batched_64": 6e4, "noop_64": 7e4}}},
    }
    rows = _cells(speed.markdown(results))
    ppo_64 = next(r for r in rows if r[:2] == ["sbagents/GridWorld-v0", "64"])
    assert {"1.20x", "1.40x"} <= set(ppo_64)  # batched / reference and no-op / reference at 64 envs
    stepping = next(r for r in rows if "7,500,000" in r)
    assert {"30.0x", "60.0x"} <= set(stepping)  # 7.5e6 / 2.5e5 and 1.5e7 / 2.5e5
    # with the rounds recorded, the per-round ratios' range follows the ratio of the medians
    env = results["envs"]["sbagents/GridWorld-v0"]  # type: ignore[index]
    env["steps_per_s_rounds"] = {"reference": [2e5, 2.5e5, 3e5], "batched": [8e6, 7.5e6, 6e6]}
    env["ppo_fps_rounds"] = {"reference_64": [5e4, 4e4], "batched_64": [6e4, 6e4]}
    rows = _cells(speed.markdown(results))
    assert "30.0x (20.00-40.00)" in next(r for r in rows if "7,500,000" in r)
    assert "1.20x (1.20-1.50)" in next(r for r in rows if r[:2] == ["sbagents/GridWorld-v0", "64"])


def test_noop_vec_env_replays_a_step_with_fresh_outputs() -> None:
    from benchmarks.speed.noop_vec_env import NoOpVecEnv
    from sbagents.batched import make_batched_vec_env

    vec = NoOpVecEnv(make_batched_vec_env("treasure_hunt_v0", 2, 0, {}, None))
    first = vec.reset()
    obs, rewards, dones, infos = vec.step(np.zeros(6, dtype=np.int64))
    again = vec.step(np.zeros(6, dtype=np.int64))
    assert obs.shape == first.shape == (6, vec.observation_space.shape[0]) and obs is not again[0]
    assert rewards.tolist() == [0.0] * 6 and not dones.any()
    assert set(infos[0]) == {"treasures_collected", "event"} and infos[0] is not again[3][0]


def test_serve_latency_tiny() -> None:
    """Both serving variants answer every timed request; the table has their ratio and memory."""
    from benchmarks.speed import serve_latency

    result = serve_latency.run_cli(["--n", "30"])
    assert result["command"] == "python -m benchmarks run serve-latency --n 30"
    for variant in ("stdio", "http"):
        row = result[variant]
        assert 0 < row["p50_us"] <= row["p99_us"] and row["rss_mib"] > 0 and row["peak_rss_mib"] >= row["rss_mib"]
    cells = _cells(serve_latency.markdown(result))
    assert cells[0][4] == "p50 / stdio" and cells[1][4] == "1.00x" and cells[2][4].endswith("x")
