"""Learning curves of finished (or running) runs as a PNG: the library side of ``python -m sbagents.plot``.

Runs of the same algo and env with different ``k`` (``<log-folder>/<algo>/<EnvId>_<k>/``) are seeds:
each env gets one panel, each algo a colour; the solid line is the mean over seeds of the smoothed training
episode returns (monitor files) and the band its spread (min to max over seeds); dashed lines with markers are
the periodic evaluations (``evaluations.npz``, mean over seeds of the per-evaluation mean return).

Timesteps are the model's (``model.num_timesteps``, as in ``evaluations.npz``): monitor episode lengths are
converted where one monitor step is not one timestep (AtariWrapper's frame skip: the monitor sits below it
and counts frames; parameter-shared PettingZoo envs: one team step is one timestep per agent).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sbagents.errors import UsageError
from sbagents.pipeline.monitor_files import read_monitor_files
from sbagents.pipeline.run_dir import RunRef, env_stem, read_settings_file

_RUN_DIR = re.compile(r"^(?P<stem>.+)_(?P<k>\d+)$")


@dataclass
class RunCurve:
    """The learning data of one run dir.

    :param returns: training episode returns in the order they ended, shape ``(n_episodes,)``.
    :param timesteps: model timesteps at the end of each of those episodes, shape ``(n_episodes,)``.
    :param eval_timesteps: timesteps of the periodic evaluations, shape ``(n_evals,)``.
    :param eval_returns: mean return of each evaluation, shape ``(n_evals,)``.
    """

    run_dir: Path
    returns: np.ndarray
    timesteps: np.ndarray
    eval_timesteps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    eval_returns: np.ndarray = field(default_factory=lambda: np.zeros(0))


def read_monitor(run_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """Episode returns and lengths from every ``*monitor.csv`` of ``run_dir``, ordered by end time."""
    episodes = read_monitor_files(run_dir)
    return episodes.returns, episodes.lengths


def timesteps_per_monitor_step(run_dir: Path, stem: str) -> float:
    """How many model timesteps one monitor step is (1/frame_skip under AtariWrapper, n_agents for teams)."""
    config = run_dir / stem / "config.yml"
    entry = read_settings_file(config) if config.exists() else {}
    wrappers = entry.get("env_wrapper") or []
    for item in wrappers if isinstance(wrappers, list) else [wrappers]:
        name, kwargs = (item, {}) if isinstance(item, str) else next(iter(dict(item).items()))
        if str(name).endswith("AtariWrapper"):
            return 1.0 / float((kwargs or {}).get("frame_skip", 4))
    args_file = run_dir / stem / "args.yml"
    args = read_settings_file(args_file) if args_file.exists() else {}
    if "timesteps_per_env_step" in args:  # PettingZoo runs record it: the first model's agents per team step
        return float(args["timesteps_per_env_step"])
    from sbagents.registration import PETTINGZOO_ENVS

    if stem in PETTINGZOO_ENVS:  # runs made before that record: all agents share one model
        from sbagents.pipeline.env_names import make_parallel_env

        env = make_parallel_env(PETTINGZOO_ENVS[stem], **(entry.get("env_kwargs") or {}))
        n_agents = len(env.possible_agents)
        env.close()
        return float(n_agents)
    return 1.0


def load_run_curve(run_dir: Path, stem: str) -> RunCurve:
    """Read the monitor files and ``evaluations.npz`` of one run dir."""
    returns, lengths = read_monitor(run_dir)
    steps = np.cumsum(lengths) * timesteps_per_monitor_step(run_dir, stem) if len(lengths) else np.zeros(0)
    curve = RunCurve(run_dir, returns, steps)
    evals = run_dir / "evaluations.npz"
    if evals.exists():
        with np.load(evals) as data:
            timesteps = np.asarray(data["timesteps"], dtype=np.float64)
            results = np.asarray(data["results"], dtype=np.float64).reshape(len(timesteps), -1)
        if results.size:  # an evaluation of zero episodes has nothing to draw
            curve.eval_timesteps, curve.eval_returns = timesteps, results.mean(axis=1)
    return curve


def find_runs(runs: RunRef) -> dict[tuple[str, str], list[Path]]:
    """Run dirs under ``runs.log_folder`` grouped by ``(algo, env stem)``, each group sorted by k; ``runs.algo`` and
    ``runs.env`` (when set) keep only theirs."""
    log_folder, algo, env = runs.log_folder, runs.algo, runs.env
    root = Path(log_folder)
    if not root.is_dir():
        raise UsageError(f"log folder {root} does not exist")
    wanted_stem = None
    if env is not None:
        wanted_stem = env_stem(env)
        try:
            from sbagents.pipeline.env_names import resolve_env

            wanted_stem = env_stem(resolve_env(env, runs.gym_packages).env_id)
        except UsageError:
            pass  # an env of a package we cannot import here: match its name as given
    groups: dict[tuple[str, str], list[tuple[int, Path]]] = {}
    algo_dirs = [root / algo] if algo is not None else sorted(p for p in root.iterdir() if p.is_dir())
    for algo_dir in algo_dirs:
        if not algo_dir.is_dir():
            continue
        for run_dir in algo_dir.iterdir():
            match = _RUN_DIR.match(run_dir.name)
            if (
                not match
                or not run_dir.is_dir()
                or (wanted_stem is not None and match["stem"] != wanted_stem)
            ):
                continue
            groups.setdefault((algo_dir.name, match["stem"]), []).append((int(match["k"]), run_dir))
    if not groups:
        what = " ".join(x for x in (algo, env) if x) or "any algo/env"
        raise UsageError(f"no runs for {what} in {root} (expected <log-folder>/<algo>/<EnvId>_<k>/)")
    return {key: [p for _, p in sorted(runs)] for key, runs in sorted(groups.items())}


def smooth(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average (the first points average what exists so far)."""
    if window <= 1 or len(values) == 0:
        return values
    sums = np.cumsum(np.insert(values, 0, 0.0))
    idx = np.arange(1, len(values) + 1)
    lo = np.maximum(idx - window, 0)
    return (sums[idx] - sums[lo]) / (idx - lo)


def _mean_band(xs: list[np.ndarray], ys: list[np.ndarray], n_points: int = 200) -> tuple[np.ndarray, ...]:
    """Interpolate every run on a common grid up to the shortest run's end; mean, min and max over runs."""
    end = min(x[-1] for x in xs)
    start = max(x[0] for x in xs)
    grid = np.linspace(start, end, n_points) if end > start else np.asarray([end])
    stacked = np.stack([np.interp(grid, x, y) for x, y in zip(xs, ys, strict=True)])
    return grid, stacked.mean(axis=0), stacked.min(axis=0), stacked.max(axis=0)


def plot(
    runs: RunRef,
    output: str | Path | None = None,
    x_axis: str = "timesteps",
    window: int = 0,
    title: str | None = None,
) -> Path:
    """Plot the learning curves of the runs under ``runs.log_folder`` to a PNG and return its path.

    :param runs: which runs: ``algo``/``env`` None means every algo folder / every env.
    :param output: PNG path (default: ``<log_folder>/learning_curves.png``).
    :param x_axis: ``"timesteps"`` (model timesteps; evaluations are drawn too) or ``"episodes"``.
    :param window: moving-average window over training episodes (0: about 1/20 of the episodes, at least 1).
    :param title: figure title (default: none; each panel is titled with its env).
    """
    log_folder = runs.log_folder
    if x_axis not in ("timesteps", "episodes"):
        raise UsageError(f"--x must be 'timesteps' or 'episodes', got {x_axis!r}")
    if window < 0:
        raise UsageError(f"--window must be >= 0 (0: automatic), got {window}")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = find_runs(runs)
    stems = sorted({stem for _, stem in groups})
    algos = sorted({a for a, _ in groups})
    colours = {a: f"C{i % 10}" for i, a in enumerate(algos)}
    fig, axes = plt.subplots(len(stems), 1, figsize=(8, 3.6 * len(stems)), squeeze=False)
    drawn = 0
    for (algo_name, stem), run_dirs in groups.items():
        ax = axes[stems.index(stem), 0]
        curves = [load_run_curve(d, stem) for d in run_dirs]
        drawn += _draw_group(ax, algo_name, curves, x_axis, window, colours[algo_name])
        ax.set_title(stem)
        ax.set_xlabel("timesteps" if x_axis == "timesteps" else "training episodes")
        ax.set_ylabel("episode return")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    if drawn == 0:
        plt.close(fig)
        raise UsageError(
            f"the runs in {log_folder} have no finished episodes yet (no monitor rows, no evaluations)"
        )
    if title:
        fig.suptitle(title, fontsize=10)
        fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 0.3 / fig.get_figheight()))
    else:
        fig.tight_layout()
    out = Path(output) if output is not None else Path(log_folder) / "learning_curves.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


def _runs_label(n: int) -> str:
    return "1 run" if n == 1 else f"mean, min-max of {n} runs"


def _draw_group(ax: Any, algo: str, curves: list[RunCurve], x_axis: str, window: int, colour: str) -> int:
    """Draw one algo's seeds on ``ax``; return the number of lines drawn."""
    drawn = 0
    train = [c for c in curves if len(c.returns) > 0]
    if train:
        xs, ys = [], []
        for c in train:
            w = window if window > 0 else max(1, len(c.returns) // 20)
            xs.append(
                c.timesteps if x_axis == "timesteps" else np.arange(1, len(c.returns) + 1, dtype=np.float64)
            )
            ys.append(smooth(c.returns, w))
        grid, mean, low, high = _mean_band(xs, ys)
        label = f"{algo} training ({_runs_label(len(train))})"
        ax.plot(grid, mean, color=colour, label=label)
        if len(train) > 1:
            ax.fill_between(grid, low, high, color=colour, alpha=0.2, linewidth=0)
        drawn += 1
    evals = [c for c in curves if len(c.eval_timesteps) > 0]
    if evals and x_axis == "timesteps":
        n = min(len(c.eval_timesteps) for c in evals)
        steps = np.mean([c.eval_timesteps[:n] for c in evals], axis=0)
        values = np.stack([c.eval_returns[:n] for c in evals])
        ax.plot(
            steps,
            values.mean(axis=0),
            "--o",
            color=colour,
            markersize=3,
            label=f"{algo} evaluation ({_runs_label(len(evals))})",
        )
        if len(evals) > 1:
            ax.fill_between(
                steps, values.min(axis=0), values.max(axis=0), color=colour, alpha=0.1, linewidth=0
            )
        drawn += 1
    return drawn
