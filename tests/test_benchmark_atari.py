"""The Atari benchmarks on tiny budgets: ``python -m benchmarks run atari-speed`` (side by side, into a tmp
Markdown) and the GPU command ``atari-gpu`` run on the CPU (every phase, its files), then rendered.

The runs are skipped without EnvPool (``pip install -e ".[atari]"``) unless ``SBAGENTS_REQUIRE_ENVPOOL=1``
(``.ci/run``); the GPU sampler (with a stand-in ``nvidia-smi``) and the batch choice are tested everywhere.
"""

from __future__ import annotations

import json
import os
import stat
import time
from pathlib import Path

import pytest
import torch
from cli_helpers import OTHER_SECTION, section_text

from benchmarks.__main__ import main as bench_main
from benchmarks.speed import atari_gpu, atari_speed
from sbagents.atari import envpool_installed

REQUIRED = os.environ.get("SBAGENTS_REQUIRE_ENVPOOL") == "1"
needs_envpool = pytest.mark.skipif(not envpool_installed() and not REQUIRED,
                                   reason='needs EnvPool: pip install -e ".[atari]"')


@pytest.fixture(autouse=True)
def _one_thread() -> None:
    torch.set_num_threads(1)



@needs_envpool
def test_atari_speed_side_by_side(tmp_path: Path) -> None:
    md, raw = tmp_path / "BENCH.md", tmp_path / "speed.json"
    md.write_text("# Benchmarks\n\n" + OTHER_SECTION)
    argv = ["--n-envs", "2", "--rounds", "1", "--env-rounds", "1", "--env-steps", "400", "--ppo-rollouts", "1",
            "--dqn-steps", "0", "--kinds", "dummy", "envpool"]
    assert bench_main(["run", "--output", str(md), "--results", str(raw), atari_speed.SECTION, *argv]) == 0
    results = json.loads(raw.read_text())
    summary = results["summary"]
    assert set(summary) == {"env", "env_cpu", "ppo_rollout", "ppo", "ppo_cpu"}  # no DQN figure asked for
    for row in summary.values():
        assert row["dummy"] > 0 and row["envpool"] > 0
        assert row["envpool/dummy"] == pytest.approx(row["envpool"] / row["dummy"])  # one round: the same ratio
    text = md.read_text()
    assert OTHER_SECTION in text
    section = section_text(text, atari_speed.SECTION)
    assert "`python -m benchmarks run atari-speed --n-envs 2 --rounds 1" in section and str(tmp_path) not in section
    assert section == f"\n{atari_speed.markdown(results)}\n"  # the body between the markers' lines
    assert "| env only |" in section and "| PPO training |" in section and "envpool / dummy" in section


def test_targets_paragraph_from_per_round_samples() -> None:
    """Ranges of the per-round ratios and the two targets, met or not, from the samples alone."""
    samples = {"env": {"dummy": [100.0, 200.0, 100.0], "envpool": [250.0, 380.0, 150.0]},
               "ppo": {"dummy": [10.0, 10.0, 10.0], "envpool": [10.5, 9.0, 10.2]}}
    results = {"samples": samples, "summary": atari_speed.summarize(samples), "machine": {"cores": 2}, "n_envs": 8}
    text = atari_speed.targets_paragraph(results)
    assert "env only 1.50-2.50x; PPO training 0.90-1.05x" in text
    assert "at least 2x DummyVecEnv + AtariWrapper: not met (1.90x)" in text  # the median of 2.5, 1.9, 1.5
    assert "PPO training faster than with DummyVecEnv: met (1.02x)" in text
    samples["env"]["envpool"] = [250.0, 420.0, 210.0]
    assert "AtariWrapper: met (2.10x)" in atari_speed.targets_paragraph({**results, "samples": samples,
                                                                          "summary": atari_speed.summarize(samples)})
    no_envpool = {**results, "samples": {"env": {"dummy": [1.0], "subproc": [1.0]}}}
    assert "not measured" in atari_speed.targets_paragraph(no_envpool)


def test_atari_speed_env_only_without_envpool() -> None:
    """The plain vec envs alone (no EnvPool needed), env-only figures: the section has their rows and ratio."""
    argv = ["--n-envs", "2", "--rounds", "1", "--env-rounds", "1", "--env-steps", "200", "--ppo-rollouts", "0",
            "--dqn-steps", "0", "--kinds", "dummy", "subproc"]
    results = atari_speed.run(argv)
    assert results["command"] == "python -m benchmarks run atari-speed " + " ".join(argv)
    assert set(results["summary"]) == {"env", "env_cpu"} and results["summary"]["env"]["subproc"] > 0
    section = atari_speed.markdown(results)
    assert "| env only |" in section and "subproc / dummy" in section and "envpool / dummy" not in section


@needs_envpool
def test_gpu_command_runs_on_cpu_and_renders(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out, results = tmp_path / "out", tmp_path / "results"
    monkeypatch.setattr(atari_gpu, "RESULTS_DIR", results)  # where run copies the curve
    data = atari_gpu.run_cli(["--out", str(out), "--device", "cpu", "--tiny", "--budget-s", "100"])
    assert sorted(p.name for p in out.iterdir()) == [atari_gpu.JSON_NAME, atari_gpu.PNG_NAME]
    assert json.loads((out / atari_gpu.JSON_NAME).read_text()) == data
    assert not data.get("errors") and data["machine"]["device"] == "cpu" and data["gpu_source"] is None
    assert set(data["compare"]["env"]) == {"dummy", "subproc", "envpool"}
    assert data["learn"]["steps"] > 0 and data["learn"]["final_eval_ale"]["n_episodes"] == 1
    assert data["eval_envpool"]["n_games"] == 4 and all(-21 <= r <= 21 for r in data["eval_envpool"]["returns"])
    section = atari_gpu.markdown(data)
    assert "`python3 -m benchmarks run atari-gpu --out $OUT --device cpu --tiny --budget-s 100`" in section
    assert str(tmp_path) not in section and "Greedy evaluation: EnvPool" in section
    assert (results / atari_gpu.PNG_NAME).stat().st_size > 1000


def test_choice_keeps_the_larger_batch_only_when_it_pays() -> None:
    row = {"n_envs": 16, "batch_size": 256}
    slow = {"ppo": {"envpool": {"fps": 1000, **row}, "envpool_x32": {"fps": 1200, "n_envs": 32, "batch_size": 512}}}
    fast = {"ppo": {"envpool": {"fps": 1000, **row}, "envpool_x32": {"fps": 1400, "n_envs": 32, "batch_size": 512}}}
    assert atari_gpu.choose(slow, tiny=False)["params"]["n_envs"] == 16
    assert atari_gpu.choose(fast, tiny=False)["params"] == {"n_envs": 32, "batch_size": 512, "n_steps": 128}
    assert atari_gpu.choose(None, tiny=False)["fps"] is None


def test_gpu_sampler_reads_nvidia_smi_stamps(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    fake = tmp_path / "nvidia-smi"  # prints what nvidia-smi prints for the query, every 0.1 s
    fake.write_text('#!/bin/sh\nwhile true; do echo "$(date +"%Y/%m/%d %H:%M:%S.%3N"), 37, 1024"; sleep 0.1; done\n')
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("PATH", f"{tmp_path}{os.pathsep}{os.environ['PATH']}")
    sampler = atari_gpu.GpuSampler()
    assert sampler.source == "nvidia-smi"
    t0 = time.perf_counter()
    time.sleep(1.0)
    sampler.track("span", t0, time.perf_counter())
    sampler.track("before", t0 - 100, t0 - 50)
    sampler.close()
    summary = sampler.summary()
    assert summary["before"] is None
    assert summary["span"] is not None and summary["span"]["util_mean"] == 37.0
    assert summary["span"]["memory_max_mib"] == 1024.0 and summary["span"]["samples"] >= 3


def test_gpu_curve_plot_is_written_in_place(tmp_path: Path) -> None:
    """The atari-gpu learning curve is drawn without EnvPool and lands under its name (no temporary file left)."""
    from benchmarks.speed.atari_gpu_parts import plot_curve

    path = tmp_path / "curve" / "atari_gpu_curve.png"
    plot_curve([[1000.0, 0.5, -21.0], [2000.0, 1.0, -19.0], [3000.0, 1.5, -18.0]], path, "Pong")
    assert path.stat().st_size > 0 and sorted(p.name for p in path.parent.iterdir()) == [path.name]
