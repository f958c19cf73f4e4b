"""Learning curves of finished (or running) runs as a PNG: the library side of ``python -m sbagents.plot``.

Runs of the same algo and env with different ``k`` (``<log-folder>/<algo>/<EnvId>_<k>/``) are seeds:
each env gets one panel, each algo a colour; the solid line is the mean over seeds of the smoothed training
episode returns (monitor files) and the band its spread (min to max over seeds); dashed lines with markers are
the periodic evaluations (``evaluations.npz``): seeds are aligned by timestep (each seed's evaluations interpolated
onto the union of their timesteps, within that seed's own range), the line and band cover the points every seed
reaches, and hollow markers the points fewer seeds reach, labelled with how many.

Files that cannot be read (a garbage ``evaluations.npz``, a monitor CSV that is not text) are skipped and told in
``notes``, one line each.

Timesteps are the model's (``model.num_timesteps``, as in ``evaluations.npz``): monitor episode lengths are
converted where one monitor step is not one timestep (AtariWrapper's frame skip: the monitor sits below it
and counts frames; parameter-shared PettingZoo envs: one team step is one timestep per agent).
"""

from __future__ import annotations

import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sbagents.core.monitor_files import read_monitor_files
from sbagents.core.run_dir import RunRef, env_stem, read_settings_file
from sbagents.errors import UsageError

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


def read_monitor(run_dir: Path, notes: list[str] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Episode returns and lengths from every ``*monitor.csv`` of ``run_dir``, ordered by end time (unreadable
    files and rows are skipped and told in ``notes``)."""
    own: list[str] = []
    episodes = read_monitor_files(run_dir, own)
    if notes is not None:
        notes.extend(f"{run_dir}: {note}" for note in own)
    return episodes.returns, episodes.lengths


def read_evaluations(path: Path, notes: list[str] | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """The timesteps and mean returns of an ``evaluations.npz`` (SB3's ``EvalCallback``), in timestep order;
    None (told in ``notes``) when the file is not one: not an npz, pickled data, no ``timesteps``/``results``,
    shapes that do not match, or values that are not finite."""
    try:
        with zipfile.ZipFile(path) as archive:
            if sum(info.file_size for info in archive.infolist()) > 64 << 20:
                raise ValueError("it unpacks to more than 64 MiB")
        with np.load(path, allow_pickle=False) as data:
            timesteps = np.asarray(data["timesteps"], dtype=np.float64).reshape(-1)
            results = np.asarray(data["results"], dtype=np.float64)
        results = results.reshape(len(timesteps), -1)
    except Exception as exc:  # noqa: BLE001 - any unreadable file: zip, pickle, key, dtype and shape errors
        reason = " ".join(str(exc).split())[:120] or type(exc).__name__
        if notes is not None:
            notes.append(f"{path} skipped: not an evaluations file ({reason})")
        return None
    if not results.size:  # an evaluation of zero episodes has nothing to draw
        return None
    means = results.mean(axis=1)
    if not (np.all(np.isfinite(timesteps)) and np.all(np.isfinite(means))):
        if notes is not None:
            notes.append(f"{path} skipped: it holds values that are not finite numbers")
        return None
    order = np.argsort(timesteps, kind="stable")
    return timesteps[order], means[order]


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
        from sbagents.core.env_names import make_parallel_env

        env = make_parallel_env(PETTINGZOO_ENVS[stem], **(entry.get("env_kwargs") or {}))
        n_agents = len(env.possible_agents)
        env.close()
        return float(n_agents)
    return 1.0


def load_run_curve(run_dir: Path, stem: str, notes: list[str] | None = None) -> RunCurve:
    """Read the monitor files and ``evaluations.npz`` of one run dir (what cannot be read is told in ``notes``)."""
    returns, lengths = read_monitor(run_dir, notes)
    steps = np.cumsum(lengths) * timesteps_per_monitor_step(run_dir, stem) if len(lengths) else np.zeros(0)
    curve = RunCurve(run_dir, returns, steps)
    evals = run_dir / "evaluations.npz"
    read = read_evaluations(evals, notes) if evals.exists() else None
    if read is not None:
        curve.eval_timesteps, curve.eval_returns = read
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
            from sbagents.core.env_names import resolve_env

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


def align_evaluations(curves: list[RunCurve]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Seeds' evaluations aligned by timestep: the union of their timesteps, and at each the mean, min and max over
    the seeds whose evaluations cover it (interpolated between a seed's own evaluations, never extrapolated) and how
    many seeds that is.

    :return: ``grid, mean, low, high, counts``, each of shape ``(n_points,)``.
    """
    grid = np.unique(np.concatenate([c.eval_timesteps for c in curves]))
    values = np.full((len(curves), len(grid)), np.nan)
    for i, c in enumerate(curves):
        inside = (grid >= c.eval_timesteps[0]) & (grid <= c.eval_timesteps[-1])
        values[i, inside] = np.interp(grid[inside], c.eval_timesteps, c.eval_returns)
    counts = np.sum(~np.isnan(values), axis=0)
    return grid, np.nanmean(values, axis=0), np.nanmin(values, axis=0), np.nanmax(values, axis=0), counts


def plot(
    runs: RunRef,
    output: str | Path | None = None,
    x_axis: str = "timesteps",
    window: int = 0,
    title: str | None = None,
    notes: list[str] | None = None,
) -> Path:
    """Plot the learning curves of the runs under ``runs.log_folder`` to a PNG and return its path.

    :param runs: which runs: ``algo``/``env`` None means every algo folder / every env.
    :param output: PNG path (default: ``<log_folder>/learning_curves.png``).
    :param x_axis: ``"timesteps"`` (model timesteps; evaluations are drawn too) or ``"episodes"``.
    :param window: moving-average window over training episodes (0: about 1/20 of the episodes, at least 1).
    :param title: figure title (default: none; each panel is titled with its env).
    :param notes: collects one line per file that was skipped because it cannot be read (``plot`` prints them).
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
        curves = [load_run_curve(d, stem, notes) for d in run_dirs]
        drawn += _draw_group(ax, algo_name, curves, x_axis, window, colours[algo_name])
        ax.set_title(stem)
        ax.set_xlabel("timesteps" if x_axis == "timesteps" else "training episodes")
        ax.set_ylabel("episode return")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:  # a run whose files were all skipped draws nothing
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
        _draw_evaluations(ax, algo, evals, colour)
        drawn += 1
    return drawn


def _draw_evaluations(ax: Any, algo: str, evals: list[RunCurve], colour: str) -> None:
    """The seeds' evaluations aligned by timestep (:func:`align_evaluations`): a dashed line (and min-max band)
    where every seed has evaluated, hollow markers where fewer have, each such stretch labelled with its count."""
    grid, mean, low, high, counts = align_evaluations(evals)
    n = len(evals)
    full = counts == n
    if full.any():
        ax.plot(grid[full], mean[full], "--o", color=colour, markersize=3,
                label=f"{algo} evaluation ({_runs_label(n)}, aligned by timestep)")
        if n > 1:
            ax.fill_between(grid[full], low[full], high[full], color=colour, alpha=0.1, linewidth=0)
    if (~full).any():
        ax.plot(grid[~full], mean[~full], "o", color=colour, markersize=4, markerfacecolor="none",
                label=f"{algo} evaluation where fewer of the {n} runs evaluated (count beside)")
        starts = np.flatnonzero(~full & np.r_[True, counts[1:] != counts[:-1]])
        for i in starts:
            ax.annotate(f"{counts[i]} of {n}", (grid[i], mean[i]), textcoords="offset points", xytext=(3, 4),
                        fontsize=7, color=colour)
