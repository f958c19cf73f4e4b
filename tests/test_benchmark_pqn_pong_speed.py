"""``pqn-pong-speed`` on a tiny budget: two rows (the baseline and its wait policy changed), each trained in a process
of its own, and the env-only comparison; the section renders from the results alone."""

from __future__ import annotations

import pytest

pytest.importorskip("envpool", reason="the benchmark steps Pong with EnvPool: pip install -e '.[atari]'")


@pytest.mark.slow  # two short PQN Pong trainings in fresh processes (~30 s here)
def test_pqn_pong_speed_quick_run_measures_each_row_in_its_own_process() -> None:
    from benchmarks.speed.pqn_pong_speed import render, run

    results = run(["--quick"])
    rows = {r["variant"]: r for r in results["rows"]}
    assert list(rows) == ["baseline", "passive-1"]
    for row in rows.values():
        assert row["fps"] > 0 and 0 < row["rollout_share"] < 1 and row["n_envs"] == 8
        assert row["gradient_passes_per_step"] == 2 and row["gradient_steps_per_1000"] == pytest.approx(15.62)
    env = results["env_only"]
    assert env["n_envs"] == 8 and all(env[k] > 0 for k in ("training_fps", "no_stack_fps", "envpool_stack1_fps",
                                                           "envpool_stack4_fps"))
    text = render(results)
    assert "| baseline |" in text and "1.00x" in text and "EnvPool's pool alone" in text
