"""Finding the run dirs under the served folders and summarizing each as one row of the runs table.

A run dir is ``<folder>/<algo>/<EnvStem>_<k>/`` (what ``train`` writes); the folder may also be one algo folder or
one run dir. Rows are cached per run and re-read only when one of the files they come from changed, so listing
hundreds of runs every few seconds reads a handful of ``stat`` results per run.
"""

from __future__ import annotations

import json
import os
import re
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from sbagents.dashboard.folders import ServedFolders
from sbagents.pipeline.monitor_files import read_monitor_files

_RUN_DIR = re.compile(r"^(?P<stem>.+)_(?P<k>\d+)$")
#: Files whose presence marks a run dir.
RUN_MARKERS = ("summary.json", "command.txt", "evaluations.npz", "0.monitor.csv")
#: A run without ``summary.json`` whose files changed this recently is shown as running.
RUNNING_WINDOW_S = 120.0


@dataclass
class RunRow:
    """One run in the runs table (``None``: unknown or not written yet).

    :param id: ``<folder index>/<path of the run dir in that folder>``, the run's address in URLs.
    :param status: ``finished``, ``interrupted``, ``running`` (no summary yet, files changing) or ``incomplete``.
    :param notes: what could not be read (a malformed or truncated file), one sentence each.
    """

    id: str
    folder: str
    algo: str
    env: str
    k: int | None
    status: str
    seed: int | None = None
    steps: int | None = None
    fps: float | None = None
    train_seconds: float | None = None
    eval_return: float | None = None
    eval_std: float | None = None
    success_rate: float | None = None
    interrupted: bool | None = None
    backend: str = "sb3"
    started: float | None = None
    updated: float | None = None
    notes: list[str] = field(default_factory=list)

    def as_json(self) -> dict[str, Any]:
        """The row as JSON-ready data."""
        return asdict(self)


def read_json(path: Path, notes: list[str]) -> Any:
    """``path``'s JSON, or None (with a note) when it is missing, truncated or malformed."""
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        notes.append(f"{path.name} could not be read ({type(exc).__name__}: {str(exc)[:80]}); showing the rest")
        return None


def read_yaml(path: Path, notes: list[str]) -> Any:
    """``path``'s YAML (safe loader), or None (with a note) when it is missing or malformed."""
    try:
        return yaml.safe_load(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, yaml.YAMLError) as exc:
        notes.append(f"{path.name} could not be read ({type(exc).__name__}); showing the rest")
        return None


def find_run_dirs(folders: ServedFolders) -> list[tuple[int, str]]:
    """``(folder index, relative path)`` of every run dir at depth 0-2 of each served folder, in folder order."""
    found: list[tuple[int, str]] = []
    for root_index, root in enumerate(folders.roots):
        pending: list[tuple[Path, int]] = [(root, 0)]
        while pending:
            folder, depth = pending.pop()
            try:
                entries = list(os.scandir(folder))
            except OSError:
                continue
            names = {e.name for e in entries}
            if any(m in names for m in RUN_MARKERS) or any(n.endswith(".monitor.csv") for n in names):
                rel = folders.relative(root_index, folder) if folder != root else ""
                if folders.resolve(root_index, rel) is not None:
                    found.append((root_index, rel))
                continue
            if depth < 2:
                pending.extend((Path(e.path), depth + 1) for e in entries if e.is_dir() and not e.name.startswith("."))
    return sorted(found)


def _signature(run_dir: Path) -> tuple[Any, ...]:
    """What a row depends on: names, sizes and mtimes of the run's top-level files and its config folder."""
    sig = []
    try:
        for entry in os.scandir(run_dir):
            if entry.is_file() and (entry.name.endswith((".json", ".csv", ".npz", ".txt")) or entry.name == "args.yml"):
                st = entry.stat()
                sig.append((entry.name, st.st_size, st.st_mtime_ns))
            elif entry.is_dir() and not entry.name.startswith(".") and (Path(entry.path) / "args.yml").exists():
                st = (Path(entry.path) / "args.yml").stat()
                sig.append((entry.name + "/args.yml", st.st_size, st.st_mtime_ns))
    except OSError:
        return ()
    return tuple(sorted(sig))


def monitor_totals(run_dir: Path) -> tuple[int, float | None]:
    """Steps and latest end time (seconds since the epoch) over the run's monitor files."""
    episodes = read_monitor_files(run_dir)
    latest = float(episodes.end_times.max()) if len(episodes.end_times) else None
    return int(episodes.lengths.sum()), latest


def config_dir(run_dir: Path) -> Path | None:
    """The run's ``<EnvStem>/`` folder with ``config.yml`` / ``args.yml``."""
    for child in sorted(run_dir.iterdir()) if run_dir.is_dir() else []:
        if child.is_dir() and ((child / "args.yml").exists() or (child / "config.yml").exists()):
            return child
    return None


def summarize_run(folders: ServedFolders, root: int, rel: str) -> RunRow:
    """Read one run dir into a :class:`RunRow` (never raises on a malformed file: notes say what was skipped)."""
    run_dir = folders.roots[root].joinpath(*Path(rel).parts) if rel else folders.roots[root]
    parts = Path(rel).parts
    match = _RUN_DIR.match(run_dir.name)
    notes: list[str] = []
    summary = read_json(run_dir / "summary.json", notes) or {}
    cfg = config_dir(run_dir)
    args = (read_yaml(cfg / "args.yml", notes) if cfg else None) or {}
    if not isinstance(summary, dict):
        notes.append("summary.json is not a JSON object")
        summary = {}
    if not isinstance(args, dict):
        args = {}
    algo = str(summary.get("algo") or args.get("algo") or (parts[-2] if len(parts) >= 2 else "?"))
    env = str(summary.get("env") or args.get("env") or (match["stem"] if match else run_dir.name))
    evaluation: dict[str, Any] = summary["eval"] if isinstance(summary.get("eval"), dict) else {}
    steps, last_episode = monitor_totals(run_dir) if not summary else (0, None)  # a summary has the steps
    command = run_dir / "command.txt"
    started = command.stat().st_mtime if command.exists() else None
    sig = _signature(run_dir)
    updated = max((s[2] for s in sig), default=0) / 1e9 or None
    if summary:
        status = "interrupted" if summary.get("interrupted") else "finished"
    elif updated is not None and time.time() - max(updated, last_episode or 0.0) < RUNNING_WINDOW_S:
        status = "running"
    else:
        status = "incomplete"
    return RunRow(
        id=f"{root}/{rel}" if rel else f"{root}",
        folder=folders.label(root),
        algo=algo,
        env=env,
        k=int(match["k"]) if match else None,
        status=status,
        seed=_num(summary.get("seed", args.get("seed")), int),
        steps=_num(summary.get("n_timesteps"), int) if summary else steps,
        fps=_num(summary.get("fps"), float),
        train_seconds=_num(summary.get("train_seconds"), float),
        eval_return=_num(evaluation.get("mean_return"), float),
        eval_std=_num(evaluation.get("std_return"), float),
        success_rate=_num(evaluation.get("success_rate"), float),
        interrupted=summary.get("interrupted") if summary else None,
        backend=str(summary.get("backend") or args.get("backend") or "sb3"),
        started=started,
        updated=updated,
        notes=notes,
    )


def _num(value: Any, kind: type) -> Any:
    try:
        return None if value is None or isinstance(value, bool) else kind(value)
    except (TypeError, ValueError):
        return None


class RunCatalog:
    """The runs table of the served folders, re-read per run only when its files changed (thread-safe)."""

    def __init__(self, folders: ServedFolders) -> None:
        self.folders = folders
        self._rows: dict[tuple[int, str], tuple[tuple[Any, ...], RunRow]] = {}
        self._lock = threading.Lock()

    def rows(self) -> list[RunRow]:
        """Every run under the served folders, newest first."""
        result = []
        for root, rel in find_run_dirs(self.folders):
            run_dir = self.folders.roots[root].joinpath(*Path(rel).parts)
            sig = _signature(run_dir)
            with self._lock:
                cached = self._rows.get((root, rel))
            # A running run's status depends on the clock, not only on its files: re-read those.
            if cached is None or cached[0] != sig or cached[1].status == "running":
                row = summarize_run(self.folders, root, rel)
                with self._lock:
                    self._rows[(root, rel)] = (sig, row)
            else:
                row = cached[1]
            result.append(row)
        return sorted(result, key=lambda r: -(r.started or 0.0))
