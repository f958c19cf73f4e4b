"""Newcomer traps: run dirs of ``module:callable`` envs, budgets that learn nothing, pixel observations without an
entry, progress after ``-i``, the clone's parent folder, and ``evaluate --env-kwargs``."""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from cli_helpers import check_error, last_json, run_main, summary
from gymnasium import spaces

from sbagents.api import EvalOptions, ExecOptions, OutputOptions, TrainSpec, train
from sbagents.core.env_kinds import TEAM
from sbagents.core.env_names import resolve_env
from sbagents.core.experiment import build_experiment
from sbagents.core.run_dir import env_stem

GRID = "sbagents/GridWorld-v0"
USER_ENVS = Path(__file__).resolve().parent / "user_envs"
REPO = Path(__file__).resolve().parents[1]

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
    assert first.kind is TEAM and first.source == "pkg_a.envs:make_env"
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


class _Pixels(gym.Env[np.ndarray, np.int64]):
    """A single-agent env of 40 x 40 RGB images (8 steps an episode; reward 1 for action 1)."""

    metadata = {"render_modes": ["rgb_array"]}
    observation_space = spaces.Box(0, 255, (40, 40, 3), np.uint8)
    action_space = spaces.Discrete(2)

    def __init__(self, render_mode: str | None = None) -> None:
        self.render_mode, self.t = render_mode, 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.t = 0
        return self.observation_space.sample(), {}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        self.t += 1
        return self.observation_space.sample(), float(action), False, self.t >= 8, {}


PIXELS = "NewcomerPixels-v0"
if PIXELS not in gym.registry:
    gym.register(PIXELS, entry_point=_Pixels)
PISTONBALL = "pettingzoo.butterfly.pistonball_v6"


def test_pixel_envs_without_an_entry_get_the_image_recipe_not_an_mlp(tmp_path: Path) -> None:
    """pistonball (20 agents x 457 x 120 x 3) and a Gymnasium image env have no entry of their own: ppo gets
    grayscale 84 x 84 frames, 4 stacked, and CnnPolicy (recorded in config.yml, so evaluate builds the same), not
    MlpPolicy on raw pixels; the env's own entry and -params policy:... are taken as they are."""
    pistonball = build_experiment(TrainSpec("ppo", PISTONBALL), resolve_env(PISTONBALL))
    assert pistonball.policy == "CnnPolicy" and pistonball.frame_stack == 4
    assert pistonball.hyperparams["env_wrapper"] == [
        {"sbagents.multiagent.preprocessing.ImagePreprocessing": {"grayscale": True, "shape": [84, 84]}}]
    insisted = build_experiment(TrainSpec("ppo", PISTONBALL, hyperparams={"policy": "MlpPolicy"}),
                                resolve_env(PISTONBALL))
    assert insisted.policy == "MlpPolicy" and not insisted.env_wrapper
    pong = "pettingzoo.butterfly.cooperative_pong_v6"  # an entry of its own: as written
    assert build_experiment(TrainSpec("ppo", pong), resolve_env(pong)).hyperparams["policies"] == "per_agent"
    result = train(TrainSpec("ppo", PIXELS, 64, {"n_envs": 1, "n_steps": 64, "batch_size": 32, "n_epochs": 1}),
                   OutputOptions(tmp_path), EvalOptions(eval_freq=0, final_eval_episodes=2), ExecOptions(seed=0))
    assert result.experiment.policy == "CnnPolicy" and result.model is not None
    assert result.model.observation_space.shape == (4, 84, 84)  # WarpFrame, 4 stacked, channel-first for the CNN
    assert result.summary["eval"]["n_episodes"] == 2


@pytest.mark.parametrize("algo", ["sac", "dqn"])
def test_pixel_envs_without_an_entry_refuse_replay_algorithms(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                              algo: str) -> None:
    env = PISTONBALL if algo == "sac" else PIXELS
    code = run_main("train", "--algo", algo, "--env", env, "-n", "256", "-f", str(tmp_path / "logs"))
    check_error(code, capsys.readouterr().err, f"has no zoo entry of its own, so {algo} would train an MLP on raw "
                                               "pixels; give it an entry with policy: CnnPolicy")
    assert not (tmp_path / "logs").exists()


_EDITABLE_LAUNCH = '''
import importlib.abc, importlib.machinery, importlib.util, runpy, sys
from pathlib import Path

REPO = Path(sys.argv[1])
FOLDERS = {"sbagents": REPO / "sbagents", "sbagents.envs": REPO / "envs", "sbagents.callbacks": REPO / "callbacks",
           "sbagents.zoo_configs": REPO / "zoo_configs"}


class EditableFinder(importlib.abc.MetaPathFinder):
    """What setuptools' editable finder does: map package names to folders, after Python's own path search."""

    def find_spec(self, fullname, path=None, target=None):
        for package in sorted(FOLDERS, key=len, reverse=True):
            if fullname == package or fullname.startswith(package + "."):
                parts = fullname[len(package):].lstrip(".").split(".") if fullname != package else []
                where = FOLDERS[package].joinpath(*parts)
                if where.is_dir():
                    return importlib.util.spec_from_file_location(
                        fullname, where / "__init__.py", submodule_search_locations=[str(where)])
                return importlib.util.spec_from_file_location(fullname, where.with_suffix(".py"))
        return None


sys.path = [p for p in sys.path if Path(p or ".").resolve() != REPO]
sys.meta_path.insert(sys.meta_path.index(importlib.machinery.PathFinder) + 1, EditableFinder())
sys.argv = ["train", "-n", "100"]
runpy.run_module("sbagents.train", run_name="__main__", alter_sys=True)
'''


def test_the_clones_parent_folder_says_why_nothing_is_registered(tmp_path: Path) -> None:
    """Started in the folder that holds a clone named ``sbagents``, an editable install imports that folder as a
    namespace package (setuptools issue 3557): one line says so, instead of "unknown env id 'sbagents/GridWorld-v0'"."""
    import subprocess

    (tmp_path / "sbagents").mkdir()  # the clone, seen from its parent: a folder without __init__.py
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run([sys.executable, "-c", _EDITABLE_LAUNCH, str(REPO)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    check_error(done.returncode, done.stderr, f"python -m sbagents.train: error: Python imported the folder "
                                              f"{(tmp_path / 'sbagents').resolve()} as sbagents instead of the "
                                              "installed package")
    assert "setuptools issue 3557" in done.stderr and "unknown env id" not in done.stderr
    assert not (tmp_path / "logs").exists()


def test_the_hint_is_also_in_the_library_error(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    import types

    from sbagents.errors import UsageError

    namespace = types.ModuleType("sbagents")
    namespace.__path__ = [str(tmp_path / "sbagents")]  # a namespace package has no __file__
    monkeypatch.setitem(sys.modules, "sbagents", namespace)
    with pytest.raises(UsageError, match="unknown env id 'Nope-v0'; Python imported the folder .*issue 3557"):
        resolve_env("Nope-v0")


def test_evaluate_and_record_video_take_env_kwargs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--env-kwargs`` (train's parser) reaches the env of ``evaluate`` and ``record_video``: the learned 8-move path
    is cut at max_steps 3 (return -3, no success), the video's episodes at 2 steps; a bad key is one line."""
    train(TrainSpec("qlearning", GRID), OutputOptions(tmp_path), EvalOptions(eval_freq=0, final_eval_episodes=0),
          ExecOptions(seed=0, verbose=0))
    run = ["--algo", "qlearning", "--env", "GridWorld-v0", "-f", str(tmp_path)]
    assert run_main("evaluate", *run, "-n", "2", "--json") == 0
    assert last_json(capsys.readouterr().out)["mean_return"] == 93.0
    assert run_main("evaluate", *run, "-n", "2", "--json", "--env-kwargs", "max_steps:3") == 0
    cut = last_json(capsys.readouterr().out)
    assert (cut["mean_return"], cut["mean_length"], cut["success_rate"]) == (-3.0, 3.0, 0.0)
    check_error(run_main("evaluate", *run, "--env-kwargs", "sise:3"), capsys.readouterr().err,
                "unknown env kwarg(s) sise for sbagents/GridWorld-v0; accepted: goal, max_steps")
    check_error(run_main("evaluate", *run, "--env-kwargs", "max_steps:" + "9" * 30), capsys.readouterr().err,
                "--env-kwargs max_steps: integer '999999999999999999999999999999' is outside the 64-bit range")
    assert run_main("record_video", *run, "-n", "6", "--env-kwargs", "max_steps:2") == 0
    sidecar = next((tmp_path / "qlearning" / f"{env_stem(GRID)}_1" / "videos").glob("*.csv"))
    rows = sidecar.read_text().splitlines()[1:]
    assert [row.split(",")[2] for row in rows] == ["0", "1"] * 3  # every episode truncated after 2 steps
