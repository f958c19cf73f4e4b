"""SB3 monitor files (``*monitor.csv``) of a run dir: one reader for the plots, the dashboard and its runs table.

A monitor file starts with ``#{"t_start": ..., "env_id": ...}``, then ``r,l,t`` (return, length, seconds since
``t_start`` at the episode's end) and one row per finished episode. A running job may have a partial last line: it
is left for the next read.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class MonitorEpisodes:
    """The finished training episodes of a run, ordered by end time.

    :param end_times: seconds since the epoch at each episode's end, shape ``(n_episodes,)``.
    :param returns: episode returns, shape ``(n_episodes,)``.
    :param lengths: episode lengths in monitor steps, shape ``(n_episodes,)``.
    :param t_start: the earliest ``t_start`` of the files (the run's start), None without files.
    """

    end_times: np.ndarray
    returns: np.ndarray
    lengths: np.ndarray
    t_start: float | None


def read_monitor_files(run_dir: Path, notes: list[str] | None = None) -> MonitorEpisodes:
    """Every ``*monitor.csv`` of ``run_dir``; unreadable files (not text, too) and malformed rows (non-numbers,
    non-finite values, negative lengths) are skipped (and told in ``notes`` when given)."""
    rows: list[tuple[float, float, float]] = []
    t0: float | None = None
    for path in sorted(run_dir.glob("*monitor.csv")):
        try:
            text = path.read_text()
        except OSError as exc:
            _note(notes, f"{path.name} could not be read ({exc.strerror})")
            continue
        except UnicodeDecodeError:
            _note(notes, f"{path.name} is not a monitor file (not text)")
            continue
        lines = text.splitlines(keepends=True)
        if lines and not lines[-1].endswith("\n"):
            lines.pop()  # a row being written
        t_start = 0.0
        if lines and lines[0].startswith("#"):
            try:
                t_start = float(json.loads(lines[0][1:]).get("t_start", 0.0))
            except (ValueError, AttributeError, TypeError):
                _note(notes, f"{path.name}: malformed first line")
            lines = lines[1:]
        t0 = t_start if t0 is None else min(t0, t_start)
        try:
            bad = _read_rows(lines, t_start, rows)
        except csv.Error as exc:
            _note(notes, f"{path.name} is not a monitor file ({exc})")
            continue
        if bad:
            _note(notes, f"{path.name}: {bad} malformed row(s) skipped")
    rows.sort()
    data = np.asarray(rows, dtype=np.float64).reshape(-1, 3)
    return MonitorEpisodes(data[:, 0], data[:, 1], data[:, 2], t0)


def _read_rows(lines: list[str], t_start: float, rows: list[tuple[float, float, float]]) -> int:
    """Append the ``(end time, return, length)`` of each well-formed CSV row to ``rows``; return how many rows were
    malformed (:class:`csv.Error` for text that is no CSV at all, such as NUL bytes)."""
    bad = 0
    for row in csv.DictReader(io.StringIO("".join(lines))):
        try:
            values = (t_start + float(row["t"]), float(row["r"]), float(row["l"]))
        except (KeyError, TypeError, ValueError):
            bad += 1
            continue
        if all(math.isfinite(v) for v in values) and values[2] >= 0:
            rows.append(values)
        else:
            bad += 1
    return bad


def _note(notes: list[str] | None, text: str) -> None:
    if notes is not None:
        notes.append(text)
