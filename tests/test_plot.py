"""``python -m sbagents.plot``: learning curves over seeds from monitor files and evaluations.npz."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib.image as mpimg
import numpy as np
import pytest
import torch
from cli_helpers import cli
from matplotlib.figure import Figure

from sbagents.api import EvalOptions, ExecOptions, OutputOptions, RunRef, TrainSpec, train
from sbagents.visualize.curves import find_runs, load_run_curve, plot, smooth, timesteps_per_monitor_step

torch.set_num_threads(1)
GRID = "sbagents/GridWorld-v0"
STEM = "sbagents_GridWorld-v0"


def test_plot_two_seeds_cli(tmp_path: Path) -> None:
    for seed in (0, 1):
        train(TrainSpec("qlearning", GRID, 3000), OutputOptions(tmp_path), EvalOptions(500, 2, final_eval_episodes=0),
              ExecOptions(seed=seed, verbose=0))
    groups = find_runs(RunRef("qlearning", "GridWorld-v0", tmp_path))
    assert list(groups) == [("qlearning", STEM)] and len(groups["qlearning", STEM]) == 2
    curves = [load_run_curve(d, STEM) for d in groups["qlearning", STEM]]
    for c in curves:
        assert len(c.returns) > 10 and np.all(np.diff(c.timesteps) > 0) and c.timesteps[-1] <= 3000
        assert list(c.eval_timesteps) == [500, 1000, 1500, 2000, 2500, 3000]
        assert c.eval_returns[-1] == 93.0  # the greedy path is learned within 3000 steps
    assert not np.array_equal(curves[0].returns, curves[1].returns)  # two seeds, two curves
    for x_axis in ("timesteps", "episodes"):
        out = tmp_path / f"curve_{x_axis}.png"
        result = cli(
            "plot", "-f", str(tmp_path), "--algo", "qlearning", "--env", GRID, "-o", str(out), "--x", x_axis
        )
        assert result.returncode == 0, result.stderr
        assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        image = mpimg.imread(out)
        assert image.shape[0] > 200 and image.shape[1] > 400 and image[..., :3].std() > 0.05


def test_default_output_and_all_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    train(TrainSpec("qlearning", GRID, 1000), OutputOptions(tmp_path), EvalOptions(-1, final_eval_episodes=0),
          ExecOptions(seed=0, verbose=0))
    titles: list[str | None] = []
    original = Figure.savefig

    def savefig(fig: Figure, *args: Any, **kwargs: Any) -> None:
        titles.append(fig._suptitle.get_text() if fig._suptitle is not None else None)
        original(fig, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", savefig)
    out = plot(RunRef(None, None, tmp_path))
    assert out == tmp_path / "learning_curves.png" and out.stat().st_size > 5000
    plot(RunRef(None, None, tmp_path), title="two seeds")
    assert titles == [None, "two seeds"]  # no figure title unless asked (the panels name their env)


def test_monitor_steps_are_converted_to_model_timesteps(tmp_path: Path) -> None:
    atari = tmp_path / "PongNoFrameskip-v4_1"
    (atari / "PongNoFrameskip-v4").mkdir(parents=True)
    (atari / "PongNoFrameskip-v4" / "config.yml").write_text(
        "env_wrapper: [stable_baselines3.common.atari_wrappers.AtariWrapper]\nframe_stack: 4\n"
    )
    assert timesteps_per_monitor_step(atari, "PongNoFrameskip-v4") == 0.25  # Monitor counts skipped frames
    team = tmp_path / "treasure_hunt_v0_1"
    (team / "treasure_hunt_v0").mkdir(parents=True)
    (team / "treasure_hunt_v0" / "config.yml").write_text("env_kwargs: {observation: egocentric}\n")
    assert timesteps_per_monitor_step(team, "treasure_hunt_v0") == 3.0  # one slot per agent
    assert timesteps_per_monitor_step(tmp_path, "sbagents_GridWorld-v0") == 1.0
    np.testing.assert_allclose(smooth(np.array([1.0, 3.0, 5.0, 7.0]), 2), [1.0, 2.0, 4.0, 6.0])


def test_errors_are_one_line_exit_2(tmp_path: Path) -> None:
    empty = cli("plot", "-f", str(tmp_path))
    assert empty.returncode == 2 and "no runs" in empty.stderr and empty.stderr.strip().count("\n") == 0
    missing = cli("plot", "-f", str(tmp_path / "nope"))
    assert missing.returncode == 2 and "does not exist" in missing.stderr
    bad_x = cli("plot", "-f", str(tmp_path), "--x", "hours")
    assert bad_x.returncode == 2 and bad_x.stderr.strip().count("\n") == 0
