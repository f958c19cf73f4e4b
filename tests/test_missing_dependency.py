"""An env whose optional dependency is missing (LunarLander without Box2D; Gymnasium raises ``DependencyNotInstalled``)
is one line naming what to install, exit 2, in ``train`` (no run dir left) and ``evaluate``, not ~70 lines of
traceback."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from cli_helpers import check_error, cli_subprocess

from sbagents.api import EvalOptions, ExecOptions, OutputOptions, TrainSpec, train

pytest.importorskip("Box2D", reason="a LunarLander run to evaluate needs Box2D while it trains")
LUNAR = "LunarLander-v3"
EXPECTED = f"{LUNAR} needs an optional dependency that is not installed: Box2D is not installed"


@pytest.fixture
def without_box2d(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """CLI subprocesses in which ``import Box2D`` fails, as where the box2d extra is not installed."""
    blocker = tmp_path / "blocker" / "Box2D"
    blocker.mkdir(parents=True)
    (blocker / "__init__.py").write_text("raise ImportError('No module named Box2D')\n")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(blocker.parent),
                                                                    os.environ.get("PYTHONPATH")])))


@pytest.mark.slow  # two fresh interpreters: ~6 s
def test_train_and_evaluate_name_the_missing_dependency(tmp_path: Path, without_box2d: None) -> None:
    logs = tmp_path / "logs"
    train(TrainSpec("ppo", LUNAR, 64, {"n_envs": 1, "n_steps": 64, "batch_size": 64}), OutputOptions(logs),
          EvalOptions(eval_freq=0, final_eval_episodes=0), ExecOptions(seed=0, verbose=0))
    before = sorted(logs.rglob("*"))
    # subprocesses: the missing dependency is simulated on their PYTHONPATH (this process has imported Box2D)
    done = cli_subprocess("evaluate", "--algo", "ppo", "--env", LUNAR, "-f", str(logs), "-n", "1")
    check_error(done.returncode, done.stderr, EXPECTED)
    assert 'pip install "gymnasium[box2d]"' in done.stderr
    fresh = tmp_path / "fresh"
    done = cli_subprocess("train", "--algo", "ppo", "--env", LUNAR, "-n", "64", "-f", str(fresh))
    check_error(done.returncode, done.stderr, EXPECTED)
    assert not fresh.exists(), "a run dir was left behind"
    assert sorted(logs.rglob("*")) == before
