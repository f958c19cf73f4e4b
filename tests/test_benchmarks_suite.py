"""The ``python -m benchmarks`` suite: each suite's run/markdown/main on tiny budgets, into a tmp Markdown."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from cli_helpers import OTHER_SECTION, section_text

from benchmarks import __main__ as suite
from benchmarks import callback_overhead, export_latency

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
    results = callback_overhead.main(["--timesteps", "1024", "--repeats", "1", "--envs", "GridWorld",
                                      "--output", str(md), "--json", str(raw)])
    grid = results["results"]["GridWorld"]
    assert list(grid) == list(callback_overhead.VARIANTS)
    assert grid["none"]["overhead_pct"] == 0.0
    assert all(len(r["samples"]) == 1 for r in grid.values())  # one repeat asked, one sample each
    for row in grid.values():  # the overhead is the fps drop against the no-callback run of the same round
        assert row["overhead_pct"] == pytest.approx(100 * (1 - row["fps_cpu"] / grid["none"]["fps_cpu"]), abs=0.1)
    assert json.loads(raw.read_text())["timesteps"] == 1024
    section = section_text(md.read_text(), "callback-overhead")
    assert "`python -m benchmarks.callback_overhead --timesteps 1024 --repeats 1 --envs GridWorld`" in section
    by_variant = {r[1]: r for r in _cells(section)[1:] if r[0] == "GridWorld"}
    assert set(by_variant) == set(grid)
    for name, row in grid.items():  # the table shows the measured numbers
        assert f"{row['fps_cpu']:,.0f}" in by_variant[name]
    with pytest.raises(ValueError, match="unknown"):
        callback_overhead.run(envs=["Pong"])


def test_export_latency_tiny(tmp_path: Path) -> None:
    md = _md_file(tmp_path)
    results = export_latency.main(["--train-steps", "0", "--latency-n", "30", "--n-observations", "50",
                                   "--output", str(md)])
    assert results["parity"]["onnx"] < 1e-4
    assert 0 < results["files"]["onnx_int8"] < results["files"]["onnx"]
    lat = results["latency"]
    assert set(lat) == {"sb3_predict", "onnx", "onnx_int8"}
    assert results["action_bounds"] == [[-1.0, 1.0], [-10.0, 10.0]]
    section = section_text(md.read_text(), "export-latency")
    cells = [c for row in _cells(section) for c in row]
    assert f"{results['files']['onnx']:,} B" in cells and f"{results['files']['onnx_int8']:,} B" in cells
    assert all(f"{row['p50_us']:.1f} us" in cells for row in lat.values())  # the table shows the measured numbers
    cmd = "python -m benchmarks.export_latency --train-steps 0 --latency-n 30 --n-observations 50 --seed 0"
    assert f"`{cmd}`" in section
    assert "untrained weights" in section and OTHER_SECTION in md.read_text()


def test_suite_dispatch_and_flags(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    calls: dict[str, Any] = {}
    monkeypatch.setattr(suite.speed, "main", lambda **kw: calls.setdefault("speed", kw))
    monkeypatch.setattr(suite.callback_overhead, "main", lambda argv: calls.setdefault("callbacks", argv))
    monkeypatch.setattr(suite.export_latency, "main", lambda argv: calls.setdefault("export", argv))
    md = _md_file(tmp_path)
    suite.main(["--quick", "--output", str(md), "--only", "speed", "--only", "callbacks", "export",
                "learning"])
    assert calls["speed"] == {"output": str(md), "json_path": None, "rounds": 3, "quick": True}
    assert calls["callbacks"][:4] == ["--timesteps", "4096", "--repeats", "1"]
    assert "--json" not in calls["callbacks"] and calls["export"][:2] == ["--train-steps", "0"]
    assert "recorded-learning" in md.read_text()  # the learning suite really ran
    calls.clear()
    suite.main(["--output", str(md), "--only", "callbacks", "--rounds", "5", "--json", str(tmp_path / "r")])
    assert set(calls) == {"callbacks"}
    assert calls["callbacks"] == ["--repeats", "5", "--output", str(md), "--json",
                                  str(tmp_path / "r" / "callback_overhead.json")]
    assert suite.json_paths("out/speed_x.json")["speed"] == str(Path("out/speed_x.json"))
    assert suite.json_paths("")["export"] is None


def test_suite_reports_failure_and_keeps_going(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def boom(argv: list[str]) -> None:
        raise RuntimeError("boom")

    monkeypatch.setattr(suite.export_latency, "main", boom)
    md = _md_file(tmp_path)
    with pytest.raises(SystemExit) as exc:
        suite.main(["--output", str(md), "--only", "export", "learning"])
    assert exc.value.code == 1
    assert "recorded-learning" in md.read_text() and "export-latency" not in md.read_text()


def test_speed_markdown_has_ratios() -> None:
    from benchmarks import speed

    kwargs_64 = speed.ppo_kwargs("sbagents/GridWorld-v0", 64)
    kwargs_8 = speed.ppo_kwargs("sbagents/GridWorld-v0", 8)
    assert kwargs_64["batch_size"] == 8 * kwargs_8["batch_size"]  # same minibatches per rollout
    results = {
        "machine": {"cpu": "x", "cores": 2, "python": "3.11", "numpy": "2", "torch": "2", "stable_baselines3": "2",
                    "date": "d", "load_before": [1.0], "load_after": [1.0]},
        "envs": {"sbagents/GridWorld-v0": {
            "config_n_envs": 8,
            "steps_per_s": {"single": 4e5, "reference": 2.5e5, "batched": 7.5e6, "noop": 1.5e7},
            "ppo_fps": {"reference_8": 2e4, "batched_8": 2.2e4, "noop_8": 2.4e4, "reference_64": 5e4,
                        "batched_64": 6e4, "noop_64": 7e4}}},
    }
    rows = _cells(speed.markdown(results))
    ppo_64 = next(r for r in rows if r[:2] == ["sbagents/GridWorld-v0", "64"])
    assert {"1.20x", "1.40x"} <= set(ppo_64)  # batched / reference and no-op / reference at 64 envs
    stepping = next(r for r in rows if "7,500,000" in r)
    assert {"30.0x", "60.0x"} <= set(stepping)  # 7.5e6 / 2.5e5 and 1.5e7 / 2.5e5


def test_noop_vec_env_replays_a_step_with_fresh_outputs() -> None:
    from benchmarks.noop_vec_env import NoOpVecEnv
    from sbagents.batched import make_batched_vec_env

    vec = NoOpVecEnv(make_batched_vec_env("treasure_hunt_v0", 2, 0, {}, None))
    first = vec.reset()
    obs, rewards, dones, infos = vec.step(np.zeros(6, dtype=np.int64))
    again = vec.step(np.zeros(6, dtype=np.int64))
    assert obs.shape == first.shape == (6, vec.observation_space.shape[0]) and obs is not again[0]
    assert rewards.tolist() == [0.0] * 6 and not dones.any()
    assert set(infos[0]) == {"treasures_collected", "event"} and infos[0] is not again[3][0]


@pytest.mark.parametrize("task", ["tictactoe", "connect4", "holdem", "tutorial"])
def test_games_sections_match_their_results(task: str) -> None:
    """BENCHMARKS.md's game sections are what ``benchmarks.games_learning --render-only`` makes of the saved results;
    every recorded run played without an illegal move and is judged by the bar its section shows."""
    from benchmarks import games_learning as games

    saved = json.loads((RESULTS / f"games_{task}.json").read_text())
    if task == "tutorial":
        shipped = {n: json.loads((RESULTS / f"games_{n}.json").read_text()) for n in games.TUTORIAL_GAMES}
        section = games.tutorial_markdown(saved, shipped)
        rows = [r for game_rows in saved["games"].values() for r in game_rows]
    else:
        section = games.game_markdown(task, saved)
        rows = saved["runs"]
        _, met = games.BARS[task]
        verdicts = [c[-1] for c in _cells(section)[1:]]
        assert verdicts == ["yes" if met(r) else "no" for r in rows]
    assert section.strip() == section_text((ROOT / "BENCHMARKS.md").read_text(), f"games-{task}").strip()
    assert sorted({r["seed"] for r in rows}) == [0, 1, 2]
    assert all(vs["illegal_moves"] == 0 for r in rows for vs in r["vs"].values())


def test_serve_latency_tiny() -> None:
    """Both serving variants answer every timed request; the table has their ratio and memory."""
    from benchmarks import serve_latency

    result = serve_latency.run(n=30)
    for variant in ("stdio", "http"):
        row = result[variant]
        assert 0 < row["p50_us"] <= row["p99_us"] and row["rss_mib"] > 0 and row["peak_rss_mib"] >= row["rss_mib"]
    cells = _cells(serve_latency.markdown(result))
    assert cells[0][4] == "p50 / stdio" and cells[1][4] == "1.00x" and cells[2][4].endswith("x")


def test_federated_section_matches_its_results() -> None:
    """BENCHMARKS.md's federated-homes section is what ``benchmarks.federated_homes --render-only`` makes of the saved
    results, and those back the claim made of them: on every seed the federated policy meets the criterion on >= 95%
    of held-out-home steps and home 0's local model does not."""
    from benchmarks import federated_homes

    saved = json.loads((RESULTS / "federated_homes.json").read_text())
    section = section_text((ROOT / "BENCHMARKS.md").read_text(), "federated-homes")
    assert federated_homes.markdown(saved).strip() == section.strip()
    assert sorted(r["seed"] for r in saved["runs"]) == [0, 1, 2]
    for run in saved["runs"]:
        rows = run["rows"]
        assert rows["federated"]["heldout_share"] >= 0.95 > rows["local only (home 0)"]["heldout_share"]
        assert run["bytes_per_round_per_home"] > 2 * 4 * run["parameters"]  # float32, down and up
        assert {p["kind"] for p in run["personal"]} == {"client", "held-out", "outside the ranges"}
