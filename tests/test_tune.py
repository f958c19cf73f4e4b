"""Optuna tuning: a study killed mid-way resumes from its SQLite file; the emitted zoo entry trains."""

from __future__ import annotations

import contextlib
import signal
import sqlite3
import time
from pathlib import Path

import optuna
import pytest
from cli_helpers import cli, popen, summary

STUDY_DB = "ppo/sbagents_GridWorld-v0_tune.db"


def finished_trials(db: Path) -> int:
    """Finished trials in the study file, read with a read-only SQLite connection: opening it through Optuna
    while the tuner creates it would race the tuner's own schema set-up (both stamp the schema version)."""
    if not db.exists():
        return 0
    try:
        with contextlib.closing(sqlite3.connect(f"file:{db}?mode=ro", uri=True)) as conn:
            (count,) = conn.execute("SELECT COUNT(*) FROM trials WHERE state IN ('COMPLETE', 'PRUNED')").fetchone()
    except sqlite3.OperationalError:  # the tables are not created yet, or the file is locked for a moment
        return 0
    return int(count)


@pytest.mark.slow  # a study of three trials (and a new interpreter)
def test_killed_study_resumes_and_best_entry_trains(tmp_path: Path) -> None:
    # plumbing, not learning: trials of 8,192 steps (a few seconds each, long enough to kill the third mid-way)
    args = ("--algo", "ppo", "--env", "GridWorld-v0", "--n-trials", "3", "-n", "8192", "-f", str(tmp_path),
            "--pruner", "none", "--n-evaluations", "3")
    proc = popen("tune", *args)  # a subprocess: it is killed (SIGKILL) mid-study
    db = tmp_path / STUDY_DB
    deadline = time.time() + 300
    while finished_trials(db) < 2:
        assert proc.poll() is None and time.time() < deadline, proc.communicate()
        time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)  # no chance to clean up: the SQLite file is all that is left
    proc.wait()
    assert finished_trials(db) == 2

    resumed = cli("tune", *args)
    assert resumed.returncode == 0, resumed.stderr
    assert finished_trials(db) == 3
    assert "study ppo-sbagents_GridWorld-v0" in resumed.stdout
    trial_lines = [line for line in resumed.stdout.splitlines() if line.startswith("trial ")]
    study = optuna.load_study(study_name="ppo-sbagents_GridWorld-v0", storage=f"sqlite:///{db}")
    last = study.trials[-1]
    assert len(trial_lines) == 1  # one line per finished trial: the one this run added
    assert trial_lines[0].startswith(f"trial {last.number}: value {last.value:.4g} | "
                                     f"learning_rate {last.params['learning_rate']:.3g}, ")
    assert "[I " not in resumed.stdout + resumed.stderr  # Optuna's own log lines stay off

    complete = cli("tune", *args)
    assert complete.returncode == 0 and "is already complete: 3 finished trials (--n-trials 3)" in complete.stdout
    best = tmp_path / "ppo" / "sbagents_GridWorld-v0_tune_best.yml"
    assert (tmp_path / "ppo" / "sbagents_GridWorld-v0_tune_history.png").stat().st_size > 0

    trained = cli("train", "--algo", "ppo", "--env", "GridWorld-v0", "-conf", str(best), "-f", str(tmp_path / "logs"),
                  "--seed", "0", "--verbose", "0", "-n", "2048")
    assert trained.returncode == 0, trained.stderr
    assert summary(tmp_path / "logs" / "ppo" / "sbagents_GridWorld-v0_1")["n_timesteps"] >= 2048


def test_bad_tune_input_is_one_line(tmp_path: Path) -> None:
    result = cli("tune", "--algo", "sac", "--env", "GridWorld-v0", "-f", str(tmp_path))
    assert result.returncode == 2 and result.stderr.count("\n") == 1
    assert "sac cannot learn sbagents/GridWorld-v0" in result.stderr
