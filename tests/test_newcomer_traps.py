"""Newcomer traps: run dirs of ``module:callable`` envs, budgets that learn nothing, pixel observations without an
entry, progress after ``-i``, the clone's parent folder, and ``evaluate --env-kwargs``."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from cli_helpers import summary

from sbagents.api import EvalOptions, ExecOptions, OutputOptions, TrainSpec, train
from sbagents.pipeline.env_names import resolve_env
from sbagents.pipeline.run_dir import env_stem

GRID = "sbagents/GridWorld-v0"
USER_ENVS = Path(__file__).resolve().parent / "user_envs"

_MAKE_ENV = '''from tiny_marl_pkg.relay_v0 import parallel_env


def make_env(**kwargs):
    return parallel_env(**kwargs)
'''


@pytest.fixture
def two_packages(tmp_path: Path) -> Iterator[None]:
    """``tests/user_envs`` and two packages whose modules both define ``make_env`` on ``sys.path``."""
    for package in ("pkg_a", "pkg_b"):
        (tmp_path / package).mkdir()
        (tmp_path / package / "__init__.py").write_text("")
        (tmp_path / package / "envs.py").write_text(_MAKE_ENV)
    sys.path[:0] = [str(tmp_path), str(USER_ENVS)]
    try:
        yield
    finally:
        sys.path.remove(str(tmp_path))
        sys.path.remove(str(USER_ENVS))
        for name in [m for m in sys.modules if m.split(".")[0] in ("pkg_a", "pkg_b")]:
            del sys.modules[name]


def test_module_callable_runs_are_named_after_module_and_callable(two_packages: None) -> None:
    """``pkg_a.envs:make_env`` and ``pkg_b.envs:make_env`` get run dirs of their own (before, both were
    ``make_env_<k>``, and ``evaluate`` picked the other's run); PettingZoo's own entry point keeps the module's
    name, so ``module:parallel_env`` and ``module`` name the same runs."""
    first, second = resolve_env("pkg_a.envs:make_env"), resolve_env("pkg_b.envs:make_env")
    assert (first.env_id, second.env_id) == ("pkg_a.envs:make_env", "pkg_b.envs:make_env")
    assert (env_stem(first.env_id), env_stem(second.env_id)) == ("pkg_a.envs_make_env", "pkg_b.envs_make_env")
    assert first.multi_agent and first.source == "pkg_a.envs:make_env"
    plain, explicit = resolve_env("tiny_marl_pkg.relay_v0"), resolve_env("tiny_marl_pkg.relay_v0:parallel_env")
    assert plain.env_id == explicit.env_id == "relay_v0"


def test_budgets_that_learn_nothing_are_one_warning_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """dqn's GridWorld entry starts learning at step 500: -n 400 never updates; ppo's takes 128 x 8 = 1,024 steps
    per rollout: -n 300 updates once. Each is one warning line on stderr and in summary.json; a fitting budget
    warns of nothing."""
    quiet = (OutputOptions(tmp_path), EvalOptions(eval_freq=0, final_eval_episodes=0), ExecOptions(seed=0))
    dqn = train(TrainSpec("dqn", GRID, 400), *quiet)
    ppo = train(TrainSpec("ppo", GRID, 300), *quiet)
    fine = train(TrainSpec("dqn", GRID, 600, {"learning_starts": 100}), *quiet)
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning: ")]
    assert lines == [
        "warning: the budget ends at 400 steps, before learning_starts (500): dqn will not update its networks; raise "
        "-n or lower learning_starts (-params learning_starts:N)",
        "warning: the budget (300 steps) is below one rollout (n_steps 128 x 8 envs = 1,024 steps): ppo takes 1,024 "
        "steps and updates once; raise -n or lower n_steps / n_envs (-params n_steps:N)",
    ]
    assert [dqn.summary["warnings"], ppo.summary["warnings"]] == [[lines[0][9:]], [lines[1][9:]]]
    assert "warnings" not in fine.summary and "warnings" not in summary(fine.run_dir)
    assert summary(dqn.run_dir)["warnings"] == dqn.summary["warnings"]


def test_progress_after_i_counts_this_runs_steps(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``-i`` continues a model of 3,072 steps for 2,048 more: the evaluation lines read x/2,048 (this run's steps
    against this run's budget), not 5,120/2,048; summary.json keeps the model's total."""
    params = {"n_envs": 2, "n_steps": 256, "batch_size": 64}
    first = train(TrainSpec("ppo", GRID, 3072, params), OutputOptions(tmp_path),
                  EvalOptions(eval_freq=0, final_eval_episodes=0), ExecOptions(seed=0, verbose=0))
    capsys.readouterr()
    model = first.run_dir / f"{env_stem(GRID)}.zip"
    second = train(TrainSpec("ppo", GRID, 2048, params, trained_agent=model), OutputOptions(tmp_path),
                   EvalOptions(eval_freq=1024, eval_episodes=1, final_eval_episodes=0), ExecOptions(seed=0))
    evals = [line.split("steps")[0] for line in capsys.readouterr().out.splitlines() if line.startswith("eval ")]
    assert evals == ["eval 1,024/2,048 ", "eval 2,048/2,048 "]
    assert second.summary["n_timesteps"] == 5120
