"""Finding the run dirs under the served folders and summarizing each as one row of the runs table.

A run dir is ``<folder>/<algo>/<EnvStem>_<k>/`` (what ``train`` writes); the folder may also be one algo folder or
one run dir. Rows are cached per run and re-read only when one of the files they come from changed, so listing
hundreds of runs every few seconds reads a handful of ``stat`` results per run.
"""

from __future__ import annotations

import os
import re
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any

from sbagents.dashboard.folders import RunFiles, ServedFolders
from sbagents.dashboard.monitors import monitor_totals
from sbagents.dashboard.safeload import read_mapping

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
                for entry in entries:
                    if entry.is_dir() and not entry.name.startswith("."):
                        path = Path(entry.path)
                        if folders.resolve(root_index, folders.relative(root_index, path)) is not None:
                            pending.append((path, depth + 1))
    return sorted(found)


def _signature(run: RunFiles) -> tuple[Any, ...]:
    """What a row depends on: names, sizes and mtimes of the run's top-level files and its config folder (files
    whose real path leaves the served folder are left out)."""
    sig = []
    try:
        entries = list(os.scandir(run.path))
    except OSError:
        return ()
    for entry in entries:
        if entry.name.endswith((".json", ".csv", ".npz", ".txt")) or entry.name == "args.yml":
            name = entry.name
        elif entry.is_dir() and not entry.name.startswith("."):
            name = f"{entry.name}/args.yml"
        else:
            continue
        st = run.stat(name)
        if st is not None:
            sig.append((name, st.st_size, st.st_mtime_ns))
    return tuple(sorted(sig))


def config_dir(run: RunFiles) -> str | None:
    """The name of the run's ``<EnvStem>/`` folder with ``config.yml`` / ``args.yml``."""
    for child in run.folders_here():
        if run.file(f"{child}/args.yml") is not None or run.file(f"{child}/config.yml") is not None:
            return child
    return None


def is_run_dir(run: RunFiles) -> bool:
    """Whether ``run`` holds one of :data:`RUN_MARKERS` (under the served folder)."""
    return any(run.file(marker) is not None for marker in RUN_MARKERS)


def summarize_run(run: RunFiles) -> RunRow:
    """Read one run dir into a :class:`RunRow` (never raises on a malformed file: notes say what was skipped)."""
    parts = PurePosixPath(run.rel).parts
    name = parts[-1] if parts else run.path.name
    match = _RUN_DIR.match(name)
    notes: list[str] = []
    summary = read_mapping(run, "summary.json", notes) or {}
    cfg = config_dir(run)
    args = (read_mapping(run, f"{cfg}/args.yml", notes) if cfg else None) or {}
    algo = str(summary.get("algo") or args.get("algo") or (parts[-2] if len(parts) >= 2 else "?"))
    env = str(summary.get("env") or args.get("env") or (match["stem"] if match else name))
    evaluation: dict[str, Any] = summary["eval"] if isinstance(summary.get("eval"), dict) else {}
    steps, last_episode = monitor_totals(run) if not summary else (0, None)  # a summary has the steps
    command = run.stat("command.txt")
    started = command.st_mtime if command is not None else None
    sig = _signature(run)
    updated = max((s[2] for s in sig), default=0) / 1e9 or None
    if summary:
        status = "interrupted" if summary.get("interrupted") else "finished"
    elif updated is not None and time.time() - max(updated, last_episode or 0.0) < RUNNING_WINDOW_S:
        status = "running"
    else:
        status = "incomplete"
    return RunRow(
        id=f"{run.root}/{run.rel}" if run.rel else f"{run.root}",
        folder=run.folders.label(run.root),
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
        interrupted=bool(summary.get("interrupted")) if summary else None,
        backend=str(summary.get("backend") or args.get("backend") or "sb3"),
        started=started,
        updated=updated,
        notes=notes,
    )


def _num(value: Any, kind: type) -> Any:
    """``value`` as ``kind`` (int or float), None when it is missing, a bool, not a number or not finite."""
    try:
        return None if value is None or isinstance(value, bool) else kind(value)
    except (TypeError, ValueError, OverflowError):
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
            run = self.folders.run(root, rel)
            if run is None:  # removed (or replaced by a symlink that leads out) since it was found
                continue
            sig = _signature(run)
            with self._lock:
                cached = self._rows.get((root, rel))
            # A running run's status depends on the clock, not only on its files: re-read those.
            if cached is None or cached[0] != sig or cached[1].status == "running":
                row = summarize_run(run)
                with self._lock:
                    self._rows[(root, rel)] = (sig, row)
            else:
                row = cached[1]
            result.append(row)
        return sorted(result, key=lambda r: -(r.started or 0.0))
