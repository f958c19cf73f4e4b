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
    assert row["n_envs"] == 4 and row["gradient_passes"] == 2  # --quick's 4 envs, the atari entry's 2 epochs
    assert all(-21 <= c["score"] <= 21 for c in row["curve"]) and 0 < row["final"]["train_s"] <= 40 + 60
    assert "| pqn | 0 | 40 |" in render(results)
    (span,) = row["trained"]  # when the part trained, and the machine's load as it stopped
    assert span["part"].startswith("PongNoFrameskip-v4_") and span["load_15min"] >= 0
    assert f"- pqn seed 0 trained {span['start']}-{span['end']} (15-minute load" in render(results)
    assert row["n_timesteps"] == 10_000_000 and "of its entry's n_timesteps (10,000,000)" in render(results)
    assert 0.9 < row["exploration_end"] <= 1.0  # PQN's epsilon, a few thousand steps into its 1M-step decay
    logs = tmp_path / "pqn" / "seed0"
    (first,) = logs.glob("pqn/PongNoFrameskip-v4_*")
    (first / "summary.json").unlink()  # as if the session had ended mid-run, after its first checkpoint
    for later in sorted(first.glob("rl_model_*_steps.zip"), key=lambda p: int(p.stem.split("_")[2]))[1:]:
        later.unlink()
    again = run(["-f", str(tmp_path), "--algos", "pqn", "--quick"])["rows"][0]
    assert again["parts"] == 2 and [t["part"] for t in again["trained"]] == [first.name, sorted(
        (p.parent.name for p in logs.rglob("command.txt")), key=lambda n: int(n.rsplit("_", 1)[1]))[-1]]
    words = sorted(logs.rglob("command.txt"))[-1].read_text().split()
    assert words[words.index("-i") + 1].endswith("_steps.zip")
    scores = json.loads((logs / "scores.json").read_text())
    assert {c["score"] for c in again["curve"]} <= {v["score"] for v in scores.values()}  # scored once, kept
    seconds = [c["train_s"] for c in again["curve"]]
    assert seconds == sorted(seconds) and again["curve"][-1]["steps"] > 2000  # the parts' seconds add up


def test_gradient_passes_per_env_step_follow_each_algorithms_config() -> None:
    """DQN's Atari recipe samples 32 transitions every 4 env steps: 8 passes per env step; PQN and PPO pass every
    transition once per epoch."""
    from benchmarks.learning.pong_cpu import gradient_passes

    assert gradient_passes("dqn", {"batch_size": 32, "train_freq": 4, "gradient_steps": 1}) == 8
    assert gradient_passes("dqn", {"batch_size": 64, "train_freq": [2, "step"], "gradient_steps": 2, "n_envs": 4}) == 16
    assert gradient_passes("ppo", {"n_epochs": 4}) == 4 and gradient_passes("pqn", {"n_epochs": 2}) == 2


def test_exploration_at_follows_sb3s_linear_schedule() -> None:
    """DQN's Atari recipe: epsilon 1 -> 0.01 over the first 10% of 10M steps; PPO has none; defaults per class."""
    from benchmarks.learning.pong_cpu import exploration_at

    dqn = {"n_timesteps": 1e7, "exploration_fraction": 0.1, "exploration_final_eps": 0.01}
    assert exploration_at("dqn", dqn, 0) == 1.0 and exploration_at("dqn", dqn, 500_000) == pytest.approx(0.505)
    assert exploration_at("dqn", dqn, 2_000_000) == 0.01
    assert exploration_at("ppo", {"n_timesteps": 1e7, "n_epochs": 4}, 10) is None
    # a setting the config leaves out is the algorithm class's default (PQN's final epsilon: 0.001)
    assert exploration_at("pqn", {"n_timesteps": 1e7}, 2_000_000) == 0.001


def test_the_gpu_setting_renders_each_parts_gpu_figures() -> None:
    """``pong-gpu`` shares pong-cpu's runs and section; a run's GPU utilisation per part becomes a column."""
    from benchmarks.learning.pong_cpu import GPU, build_parser, render

    args = build_parser(GPU).parse_args(["-f", "OUT"])
    assert (args.device, args.budget_s, args.num_threads) == ("cuda", 600.0, 1)
    point = {"steps": 2_000_000, "train_s": 590.0, "score": 19.5, "score_std": 1.0, "games": 10}
    row = {"algo": "pqn", "seed": 0, "budget_s": 600.0, "n_envs": 128, "gradient_passes": 2.0, "parts": 1,
           "steps_per_s": 3389.8, "final": point, "best": point, "curve": [point], "num_threads": 1,
           "first_target": {**point, "train_s": 600.0},
           "gpu": {"PongNoFrameskip-v4_1": {"util_mean": 41.0, "util_max": 77.0, "memory_max_mib": 2100.0,
                                            "samples": 1180}}}
    machine = {"cores": 16, "cpu": "x", "date": "d", "load_before": [0.1], "load_after": [9.0], "gpu": "H100"}
    text = render({"command": "c", "earlier_commands": [], "rows": [row], "stats": {}, "machine": machine,
                   "where": GPU.where, "plot": GPU.plot})
    assert "## Pong on one GPU (H100) and 16 cores" in text and "GPU busy % (mean, max) |" in text
    assert "| 10, 2,000,000 | 1 | 41, 77 |" in text and "pong_gpu.png" in text
