"""The learning curves of the Kuka benchmarks: read from ``sbagents.train`` run dirs, plotted, kept in the results,
rendered as the sections' tables.

A run (one entry of a report's ``runs`` in the results) is the run dir's evaluation history and summary::

    {"label", "env_id", "algo", "n_timesteps", "steps": [...], "success": [...], "mean_return": [...],
     "final_success", "final_episodes", "train_s", "fps", "command"}

``success`` holds the success rate of each evaluation (None where the env reports none). A section is a list of
blocks (results ``blocks``): verbatim Markdown (``{"text": ...}``) or a table of a report (``{"summary": KEY}``,
``{"curve": KEY}``, ``{"commands": KEY}``), so notes written once stay beside the tables the numbers make.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from benchmarks.report import save_figure


@dataclass
class Curve:
    """One run's evaluation history.

    :param label: legend label.
    :param env_id: environment id.
    :param steps: ``(n_evals,)`` env steps at each evaluation.
    :param success: ``(n_evals,)`` success rate of each evaluation (NaN if the env reports none).
    :param mean_return: ``(n_evals,)`` mean evaluation return.
    :param n_episodes: evaluation episodes per point.
    :param summary: the run's ``summary.json`` (empty if missing).
    :param command: the training command (``command.txt``), if recorded.
    """

    label: str
    env_id: str
    steps: np.ndarray
    success: np.ndarray
    mean_return: np.ndarray
    n_episodes: int
    summary: dict[str, Any]
    command: str


def _summary(run_dir: Path) -> dict[str, Any]:
    """``summary.json``, or for a run still going: algo and env from ``args.yml``, wall time from the monitor."""
    summary_path = run_dir / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    if summary:
        return summary
    for args_path in run_dir.glob("*/args.yml"):
        args = yaml.safe_load(args_path.read_text()) or {}
        summary = {"algo": args.get("algo"), "env": args.get("env")}
    monitor = run_dir / "0.monitor.csv"
    if monitor.exists():
        rows = monitor.read_text().strip().splitlines()
        if len(rows) > 2:
            summary["train_seconds"] = float(rows[-1].split(",")[2])
    return summary


def load_curve(label: str, run_dir: str | Path) -> Curve:
    """Read ``evaluations.npz``, ``summary.json`` and ``command.txt`` of a ``sbagents.train`` run dir."""
    run_dir = Path(run_dir)
    data = np.load(run_dir / "evaluations.npz")
    results = np.asarray(data["results"], dtype=np.float64)
    if "successes" in data and np.asarray(data["successes"]).size:
        success = np.asarray(data["successes"], dtype=np.float64).mean(axis=1)
    else:
        success = np.full(len(results), np.nan)
    summary = _summary(run_dir)
    command_path = run_dir / "command.txt"
    command = command_path.read_text().strip() if command_path.exists() else ""
    env_id = str(summary.get("env") or run_dir.name.rsplit("_", 1)[0])
    return Curve(label, env_id, np.asarray(data["timesteps"]), success, results.mean(axis=1),
                 results.shape[1], summary, command)


def portable(command: str, log_folder: Path | None) -> str:
    """``command`` with ``log_folder`` (absolute or as given) written ``<output dir>``."""
    if log_folder is None:
        return command
    for form in sorted({str(log_folder.resolve()), str(log_folder)}, key=len, reverse=True):
        command = command.replace(form, "<output dir>")
    return command


def curve_run(c: Curve, log_folder: Path | None = None) -> dict[str, Any]:
    """The results entry of one run (``log_folder`` written ``<output dir>`` in its command)."""
    s, ev = c.summary, c.summary.get("eval") or {}
    n_steps = int(s.get("n_timesteps", c.steps[-1]))
    seconds = float(s.get("train_seconds", float("nan")))
    fps = float(s.get("fps", n_steps / seconds if seconds > 0 else float("nan")))
    return {"label": c.label, "env_id": c.env_id, "algo": s.get("algo", "?"), "n_timesteps": n_steps,
            "steps": [int(t) for t in c.steps], "success": [None if math.isnan(v) else float(v) for v in c.success],
            "mean_return": [float(v) for v in c.mean_return], "final_success": ev.get("success_rate"),
            "final_episodes": ev.get("n_episodes"), "train_s": None if math.isnan(seconds) else seconds,
            "fps": None if math.isnan(fps) else fps, "command": portable(c.command, log_folder)}


def plot_curves(curves: list[Curve], path: Path, title: str) -> None:
    """Success rate (left) and mean evaluation return (right) vs env steps, one line per run (written to a temporary
    name and renamed into place)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_s, ax_r) = plt.subplots(1, 2, figsize=(11, 4))
    for c in curves:
        name = f"{c.label}: {c.env_id}"
        ax_s.plot(c.steps, 100 * c.success, marker="o", ms=3, label=name)
        ax_r.plot(c.steps, c.mean_return, marker="o", ms=3, label=name)
    ax_s.set(xlabel="env steps", ylabel="success rate (%)", ylim=(-3, 103), title="deterministic evaluation")
    ax_r.set(xlabel="env steps", ylabel="mean return", title="(returns are not comparable across envs)")
    for ax in (ax_s, ax_r):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def _pct(value: float | None) -> str:
    return "nan%" if value is None else f"{100 * value:.0f}%"


def summary_table(report: dict[str, Any]) -> str:
    """One row per run: steps, best / last / final evaluation success, train time and speed."""
    lines = [f"1 seed (seed {report['seed']}) per run: single training runs, so no interval over seeds.", "",
             "| run | env | algo | steps | best eval success | last eval success | final eval success "
             "(episodes) | train time (s) | steps/s |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in report["runs"]:
        known = [v for v in r["success"] if v is not None]
        final = "n/a" if r["final_success"] is None else f"{_pct(r['final_success'])} ({r['final_episodes'] or '?'})"
        seconds = "nan" if r["train_s"] is None else f"{r['train_s']:.0f}"
        fps = "nan" if r["fps"] is None else f"{r['fps']:.0f}"
        lines.append(f"| {r['label']} | `{r['env_id']}` | {r['algo']} | {r['n_timesteps']} "
                     f"| {_pct(max(known) if known else None)} | {_pct(r['success'][-1])} | {final} | {seconds} "
                     f"| {fps} |")
    return "\n".join(lines)


def curve_table(report: dict[str, Any]) -> str:
    """Success rate (%) of every run at every evaluation step."""
    runs = report["runs"]
    lines = [f"Success rate (%) at each evaluation ({report['n_episodes']} deterministic episodes):", "",
             "| steps | " + " | ".join(r["label"] for r in runs) + " |", "|---:|" + "---:|" * len(runs)]
    by_step = [dict(zip(r["steps"], r["success"], strict=True)) for r in runs]
    for t in sorted({t for r in runs for t in r["steps"]}):
        cells = ["" if t not in s or s[t] is None else f"{100 * s[t]:.0f}" for s in by_step]
        lines.append(f"| {t} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def commands_list(report: dict[str, Any]) -> str:
    """The training command of each run."""
    return "\n".join(["Commands:", ""] + [f"- {r['label']}: `{r['command']}`" for r in report["runs"] if r["command"]])


_TABLES = {"summary": summary_table, "curve": curve_table, "commands": commands_list}


def render_blocks(results: dict[str, Any]) -> str:
    """The section: its blocks in order, verbatim text or a report's table, a blank line between blocks."""
    reports = {r["key"]: r for r in results["reports"]}
    out = []
    for block in results["blocks"]:
        if "text" in block:
            out.append(block["text"])
            continue
        (kind, key), = block.items()
        out.append(_TABLES[kind](reports[key]))
    return "\n\n".join(out)


def default_blocks(report: dict[str, Any], heading: str, note: str, image: str) -> list[dict[str, str]]:
    """The blocks of a freshly measured report: heading, note, its three tables and its plot."""
    key = report["key"]
    return [{"text": heading}, *([{"text": note.strip()}] if note else []), {"summary": key}, {"curve": key},
            {"commands": key}, {"text": f"![success vs steps]({image})"}]
