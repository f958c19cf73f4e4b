"""The learning-from-demonstrations benchmarks on tiny budgets: ``kuka-pick-demos`` (SAC + HER with demonstrations and
behaviour cloning alone, kept runs reused), ``dqn-demos`` (demonstration replay and DQfD's margin loss) and the scripted
Panda grasp that gives panda-gym's pick-and-place its demonstrations."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("minari", reason="needs Minari: pip install -e '.[test]' (or the data extra)")


def test_kuka_pick_demos_quick_run_keeps_finished_runs(tmp_path: Path) -> None:
    from benchmarks.learning.kuka_pick_demos import render, run

    results = run(["-f", str(tmp_path), "--quick", "--variants", "demos", "bc"])
    rows = {r["variant"]: r for r in results["rows"]}
    assert set(rows) == {"demos", "bc", "none"}  # none: the stored kuka-pick-learning run
    assert rows["demos"]["n_timesteps"] == 3000 and rows["demos"]["demos"]["transitions"] == 250  # 5 x 50 steps
    assert rows["bc"]["pretrain"]["n_train"] + rows["bc"]["pretrain"]["n_holdout"] == 250
    assert all(0 <= r["final_success"] <= 1 for r in rows.values())
    section = render(results)
    assert "| demos | sbagents/KukaPickAndPlace-v0 | 0 | 3,000 |" in section
    again = run(["-f", str(tmp_path), "--quick", "--variants", "demos"])  # kept: read, not trained again
    assert again["rows"][0]["wall_s"] is None and again["rows"][0]["final_success"] == rows["demos"]["final_success"]
    with pytest.raises(SystemExit, match="'nope' is not one of"):
        run(["-f", str(tmp_path), "--quick", "--variants", "nope"])


def test_kuka_pick_demos_continues_a_stopped_run_from_its_checkpoint(tmp_path: Path) -> None:
    """A run that stopped after a checkpoint (a session that ended) goes on from it with ``-i``, its replay buffer and
    no ``--pretrain``; its row counts the model's steps and names the step it continued from."""
    from benchmarks.learning.kuka_pick_demos import run

    run(["-f", str(tmp_path), "--quick", "--steps", "2000", "--variants", "demos"])
    stopped = tmp_path / "demos" / "seed0-n3000"  # a 3000-step run whose last checkpoint was at step 2000
    (tmp_path / "demos" / "seed0-n2000").rename(stopped)
    (summary,) = stopped.rglob("summary.json")
    summary.unlink()
    (row, *_) = run(["-f", str(tmp_path), "--quick", "--variants", "demos"])["rows"]
    assert row["resumed_from"] == [2000] and row["n_timesteps"] == 3000 and row["pretrain"] is None
    assert row["demos"]["loss_steps"] > 0 and row["wall_s"] is not None
    words = sorted(stopped.rglob("command.txt"))[-1].read_text().split()
    assert words[words.index("-n") + 1] == "1000" and words[words.index("-i") + 1].endswith("rl_model_2000_steps.zip")
    assert "--pretrain" not in words and "--demos" in words


def test_kuka_pick_demos_variants_take_their_seeds_and_budget() -> None:
    from benchmarks.learning.kuka_pick_demos import _jobs

    defaults = {"demos": 200_000, "bc": 100}
    assert _jobs(["demos@500000", "bc:1"], [0, 2], defaults) == [("demos", 0, 500_000), ("demos", 2, 500_000),
                                                                  ("bc", 1, 100)]
    with pytest.raises(SystemExit, match="demos is given two budgets"):
        _jobs(["demos:0@500000", "demos:1"], [0], defaults)
    with pytest.raises(SystemExit, match="@STEPS takes a whole number"):
        _jobs(["demos@5e5"], [0], defaults)


def test_kuka_pick_demos_keeps_the_published_rows_it_does_not_train(tmp_path: Path) -> None:
    """Seeds measured by an earlier command (another session) stay in the table beside the new ones; a pair the
    command trains replaces its published row; the stored ``none`` row is left to :func:`_stored_none`."""
    import json

    from benchmarks.learning.kuka_pick_demos import _earlier, render, run

    def row(variant: str, seed: int, success: float) -> dict[str, object]:
        return {"variant": variant, "seed": seed, "final_success": success}

    published = tmp_path / "kuka_pick_demos.json"
    published.write_text(json.dumps({"command": "B", "earlier_commands": ["A"], "rows": [
        row("demos", 0, 0.98), row("demos", 1, 1.0), {**row("none", 0, 0.0), "stored": "kuka-pick-learning"}]}))
    kept, commands = _earlier([("demos", 1, 500_000), ("none", 1, 500_000)], published)
    assert kept == [row("demos", 0, 0.98)] and commands == ["A", "B"]
    assert _earlier([("demos", 0, 1), ("demos", 1, 1)], published) == ([], [])
    assert _earlier([], tmp_path / "missing.json") == ([], [])
    results = run(["-f", str(tmp_path / "out"), "--quick", "--variants", "bc"])  # a smoke run keeps nothing
    assert results["earlier_commands"] == [] and {r["variant"] for r in results["rows"]} == {"bc", "none"}
    assert "after `" not in render(results)
    section = render({**results, "earlier_commands": ["A", "B"]})
    assert section.startswith("## ") and "`, after `B`, after `A` (the rows of runs" in section


def test_dqn_demos_quick_run() -> None:
    from benchmarks.learning.dqn_demos import render, run

    results = run(["--quick"])
    assert {(r["env"], r["variant"]) for r in results["rows"]} == {
        (env, variant) for env in ("sbagents/GridWorld-v0", "sbagents/HazardGridWorld-v0")
        for variant in ("none", "replay", "margin")}
    assert "| sbagents/GridWorld-v0 | 600 | margin |" in render(results)


def test_the_scripted_panda_grasp_succeeds(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("panda_gym", reason="the Panda variants need panda-gym: pip install panda-gym")
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    from benchmarks.learning.panda_pick import record

    assert record("bench/panda-v0", 5, 0) == 1.0
    assert (tmp_path / "bench" / "panda-v0").is_dir()
