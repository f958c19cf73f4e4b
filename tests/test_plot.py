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
        train(TrainSpec("qlearning", GRID, 3000), OutputOptions(tmp_path),
              EvalOptions(eval_freq=500, eval_episodes=2, final_eval_episodes=0), ExecOptions(seed=seed, verbose=0))
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
    train(TrainSpec("qlearning", GRID, 1000), OutputOptions(tmp_path), EvalOptions(eval_freq=-1, final_eval_episodes=0),
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


def _fake_run(root: Path, k: int, eval_steps: list[int], eval_returns: list[float]) -> Path:
    """A run dir with a monitor file of two episodes and the given periodic evaluations (two episodes each)."""
    run_dir = root / "ppo" / f"{STEM}_{k}"
    run_dir.mkdir(parents=True)
    (run_dir / "0.monitor.csv").write_text('#{"t_start": 1.0, "env_id": "x"}\nr,l,t\n1.0,10,0.1\n2.0,10,0.2\n')
    results = np.repeat(np.asarray(eval_returns, dtype=np.float64)[:, None], 2, axis=1)
    np.savez(run_dir / "evaluations.npz", timesteps=np.asarray(eval_steps), results=results)
    return run_dir


def test_evaluations_are_aligned_by_timestep_not_by_index(tmp_path: Path) -> None:
    """Three seeds that evaluated once each, at 5k, 53k and 2k: three points of one run each, not one mean point
    at ~20k; seeds with the same schedule but different lengths: a mean where all three evaluated, counts beyond."""
    from sbagents.visualize.curves import align_evaluations

    odd = [load_run_curve(_fake_run(tmp_path / "a", k, [s], [r]), STEM)
           for k, (s, r) in enumerate([(5000, 10.0), (53000, 50.0), (2000, 0.0)], start=1)]
    grid, mean, low, high, counts = align_evaluations(odd)
    assert grid.tolist() == [2000, 5000, 53000] and mean.tolist() == [0.0, 10.0, 50.0]
    assert counts.tolist() == [1, 1, 1]
    runs = [load_run_curve(_fake_run(tmp_path / "b", k, steps, rets), STEM) for k, (steps, rets) in enumerate([
        ([1000, 2000, 3000], [0.0, 10.0, 20.0]), ([1000, 2000], [2.0, 4.0]), ([1500, 2500, 3500], [1.0, 3.0, 5.0])],
        start=1)]
    grid, mean, low, high, counts = align_evaluations(runs)
    assert grid.tolist() == [1000, 1500, 2000, 2500, 3000, 3500]
    assert counts.tolist() == [2, 3, 3, 2, 2, 1]  # each seed counts only inside its own evaluated range
    np.testing.assert_allclose(mean[1:3], [(5.0 + 3.0 + 1.0) / 3, (10.0 + 4.0 + 2.0) / 3])  # interpolated at 1500
    np.testing.assert_allclose([low[2], high[2]], [2.0, 10.0])
    out = plot(RunRef("ppo", None, tmp_path / "b"), tmp_path / "b.png")
    assert out.stat().st_size > 5000


@pytest.mark.parametrize(("what", "content"), [
    ("evaluations.npz", b"\x93NUMPY garbage \x00\xff" * 20),
    ("evaluations.npz", None),  # an npz without the expected arrays
    ("0.monitor.csv", bytes(range(256))),
    ("0.monitor.csv", b'#{"t_start": null}\nr,l,t\n1,2,x\nnan,1,1\n1,-1,1\n'),
])
def test_garbage_files_are_warning_lines(tmp_path: Path, what: str, content: bytes | None) -> None:
    run_dir = _fake_run(tmp_path, 1, [1000, 2000], [1.0, 2.0])
    if content is None:
        np.savez(run_dir / what, foo=np.zeros(3))
    else:
        (run_dir / what).write_bytes(content)
    done = cli("plot", "-f", str(tmp_path), "-o", str(tmp_path / "c.png"))
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    warnings = done.stderr.strip().splitlines()
    assert warnings and all(w.startswith("python -m sbagents.plot: warning: ") and what in w for w in warnings)
    assert (tmp_path / "c.png").exists()


def test_nothing_readable_is_one_error_line(tmp_path: Path) -> None:
    run_dir = _fake_run(tmp_path, 1, [1000], [1.0])
    (run_dir / "evaluations.npz").write_bytes(b"PK\x03\x04 not a zip")
    (run_dir / "0.monitor.csv").write_text("r,l,t\ngar\x00bage\n")
    done = cli("plot", "-f", str(tmp_path))
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert lines[-1].startswith("python -m sbagents.plot: error: the runs in") and len(lines) == 3, done.stderr
