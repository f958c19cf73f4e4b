"""Training curves from the SB3 monitor files (``*monitor.csv``) of a run, streamed: bounded memory whatever a
file's size, and read incrementally across requests.

A monitor file is ``#{"t_start": ...}``, then ``r,l,t`` (return, length, seconds since ``t_start`` at the episode's
end) and one row per finished episode (the format :mod:`sbagents.core.monitor_files` reads whole for the plots);
a row with a cell that is not a finite number is malformed. Each file has one :class:`MonitorFile`, shared
process-wide and continued on every read: each reads at most :data:`READ_BYTES` more of it,
:data:`CHUNK_BYTES` at a time (rows parsed by numpy, a chunk with a malformed row line by line). Totals (episodes,
steps, latest end) are exact; the episodes themselves are kept decimated: every ``stride``-th one (the stride
doubles when more than :data:`MAX_KEPT` are kept), each with the steps since the previous kept one, so the cumulative
timesteps stay right at every kept episode. A first line or row over :data:`MAX_LINE_BYTES` is skipped with a note;
a file replaced by another (other inode, or smaller) is read again.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np

from sbagents.dashboard.folders import RunFiles, open_regular
from sbagents.dashboard.logsources import BoundedLines

#: Bytes of one monitor file read per request (a bigger file is read over the next requests).
READ_BYTES = 32 << 20
#: Bytes read and parsed at a time.
CHUNK_BYTES = 1 << 20
#: A line longer than this is skipped (a monitor row is a few dozen bytes).
MAX_LINE_BYTES = 64 << 10
#: Episodes kept per file; beyond, every second kept one is dropped (and the stride doubles).
MAX_KEPT = 10_000
#: Episodes one curve sends at most (evenly spaced among the kept ones of all files).
MAX_POINTS = 20_000

_FIELDS = ("end", "ret", "length", "steps")


class MonitorFile:
    """One monitor file, read incrementally (:meth:`update`); every method is thread-safe.

    :param path: the file's real path (under a served folder).
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._lock = threading.Lock()
        self._reset(None)

    def _reset(self, inode: int | None) -> None:
        self.inode = inode
        self.offset = 0  # bytes of the file consumed
        self.t_start: float | None = None  # None until the first line was seen
        self.columns: tuple[int, int, int] | None = None  # indices of r, l, t once the header was read
        self.broken: str | None = None  # why the rest of the file is not read
        self.episodes = 0
        self.steps = 0.0
        self.last_end: float | None = None
        self.bad_first_line = False
        self.bad_rows = 0
        self.long_lines = 0
        self.stride = 1
        self._lines_in = BoundedLines(MAX_LINE_BYTES)
        self._pending = 0.0  # steps of the episodes after the last kept one
        self._kept: list[dict[str, np.ndarray]] = []
        self._n_kept = 0
        self.size = 0

    # ------------------------------------------------------------------ reading
    def update(self, read_bytes: int | None = None) -> None:
        """Read up to ``read_bytes`` (default :data:`READ_BYTES`) more of the file (from the start if it was replaced
        or truncated)."""
        with self._lock:
            try:
                fh = open_regular(self.path)
            except OSError:
                return
            with fh:
                st = os.fstat(fh.fileno())
                if st.st_ino != self.inode or st.st_size < self.offset:
                    self._reset(st.st_ino)
                self.size = st.st_size
                fh.seek(self.offset)
                left = READ_BYTES if read_bytes is None else read_bytes
                while left > 0 and self.broken is None:
                    data = fh.read(min(CHUNK_BYTES, left))
                    if not data:
                        break
                    self.offset += len(data)
                    left -= len(data)
                    self._feed(data)

    def _feed(self, data: bytes) -> None:
        block, dropped = self._lines_in.feed(data)
        if block:
            self._lines(block)
        if dropped:
            self.long_lines += 1
            if self.columns is None and self.broken is None:
                self.broken = f"{self.path.name}: a first line over {MAX_LINE_BYTES:,} bytes (not a monitor file)"

    def _lines(self, block: bytes) -> None:
        """Parse complete lines: the ``#{...}`` line and the header first, then rows."""
        while self.columns is None and block and self.broken is None:
            nl = block.index(b"\n")
            line, block = block[:nl].decode("utf-8", "replace").strip(), block[nl + 1 :]
            if self.t_start is None:
                self.t_start = 0.0
                if line.startswith("#"):
                    t_start = _t_start(line[1:])
                    self.bad_first_line = t_start is None
                    self.t_start = t_start or 0.0
                    continue
            if not line:
                continue
            names = [n.strip() for n in line.split(",")]
            if not {"r", "l", "t"} <= set(names):
                self.broken = f"{self.path.name}: no r,l,t header (not a monitor file)"
                return
            self.columns = (names.index("r"), names.index("l"), names.index("t"))
        if self.columns is not None and block:
            self._add(self._parse(block))

    def _parse(self, block: bytes) -> np.ndarray:
        """Rows ``(r, l, t)`` of complete lines; malformed ones are counted and skipped."""
        assert self.columns is not None
        try:
            return np.loadtxt(io.BytesIO(block), delimiter=",", usecols=self.columns, ndmin=2, comments=None,
                              dtype=np.float64, encoding="utf-8")
        except ValueError:  # a malformed row somewhere in the chunk: line by line
            pass
        rows = []
        for line in block.decode("utf-8", "replace").split("\n"):
            if not line.strip():
                continue
            try:
                cells = next(csv.reader([line.replace("\x00", "")]))
                rows.append([float(cells[i]) for i in self.columns])
            except (csv.Error, IndexError, ValueError):
                self.bad_rows += 1
        return np.asarray(rows, dtype=np.float64).reshape(-1, 3)

    @np.errstate(invalid="ignore", over="ignore")  # sums of huge values become inf (sent as null)
    def _add(self, rows: np.ndarray) -> None:
        """Count ``rows`` and keep every ``stride``-th episode (with the steps since the previous kept one)."""
        finite = np.isfinite(rows).all(axis=1)
        self.bad_rows += int((~finite).sum())
        rows = rows[finite]
        n = len(rows)
        if n == 0:
            return
        returns, lengths, times = rows[:, 0], rows[:, 1], rows[:, 2]
        ends = times + (self.t_start or 0.0)
        index = np.arange(self.episodes, self.episodes + n)
        self.episodes += n
        self.steps += float(lengths.sum())
        self.last_end = max(self.last_end or -np.inf, float(ends.max()))
        keep = np.flatnonzero(index % self.stride == 0)
        total = np.cumsum(lengths)
        if keep.size == 0:
            self._pending += float(total[-1])
            return
        before = np.concatenate([[0.0], total[keep[:-1]]])
        steps = total[keep] - before
        steps[0] += self._pending
        self._pending = float(total[-1] - total[keep[-1]])
        self._kept.append({"index": index[keep], "end": ends[keep], "ret": returns[keep], "length": lengths[keep],
                           "steps": steps})
        self._n_kept += keep.size
        while self._n_kept > MAX_KEPT:
            self._halve()

    def _halve(self) -> None:
        """Double the stride: keep every second kept episode, their steps summed into the next kept one."""
        kept = self.kept()
        self.stride *= 2
        keep = np.flatnonzero(kept["index"] % self.stride == 0)
        total = np.cumsum(kept["steps"])
        before = np.concatenate([[0.0], total[keep[:-1]]])
        merged = {k: v[keep] for k, v in kept.items()}
        merged["steps"] = total[keep] - before
        self._pending += float(total[-1] - total[keep[-1]])
        self._kept = [merged]
        self._n_kept = keep.size

    def kept(self) -> dict[str, np.ndarray]:
        """The kept episodes: ``index``, ``end`` (seconds since the epoch), ``ret``, ``length``, ``steps``."""
        if len(self._kept) != 1:
            self._kept = [{k: np.concatenate([c[k] for c in self._kept]) if self._kept else np.empty(0)
                           for k in ("index", *_FIELDS)}]
        return self._kept[0]

    def notes(self) -> list[str]:
        """What was skipped, and how much of the file is still to be read."""
        out = [self.broken] if self.broken else []
        if self.bad_first_line:
            out.append(f"{self.path.name}: malformed first line")
        if self.bad_rows:
            out.append(f"{self.path.name}: {self.bad_rows} malformed row(s) skipped")
        if self.long_lines and not self.broken:
            out.append(f"{self.path.name}: {self.long_lines} line(s) over {MAX_LINE_BYTES:,} bytes skipped")
        if self.broken is None and self.size > self.offset:
            out.append(f"{self.path.name}: {100 * self.offset / self.size:.0f}% read; the rest comes with the next "
                       "refreshes")
        return out

    def snapshot(self) -> tuple[dict[str, np.ndarray], float | None, list[str]]:
        """Copies of the kept episodes, ``t_start`` and the notes, taken together."""
        with self._lock:
            return {k: v.copy() for k, v in self.kept().items()}, self.t_start, self.notes()


def _t_start(text: str) -> float | None:
    """``t_start`` of a monitor file's first line (without its ``#``), None when it is malformed."""
    try:
        meta = json.loads(text)
        t_start = float(meta.get("t_start", 0.0)) if isinstance(meta, dict) else math.nan
    except (ValueError, TypeError, OverflowError, RecursionError):
        return None
    return t_start if math.isfinite(t_start) else None


_FILES: dict[Path, MonitorFile] = {}
_FILES_LOCK = threading.Lock()


def monitor_files(run: RunFiles, read_bytes: int | None = None) -> list[MonitorFile]:
    """The run's monitor files, each read up to ``read_bytes`` (default :data:`READ_BYTES`) further (one
    :class:`MonitorFile` per real path)."""
    out = []
    for name in run.glob("*monitor.csv"):
        path = run.file(name)
        if path is None:
            continue
        with _FILES_LOCK:
            monitor = _FILES.setdefault(path, MonitorFile(path))
        monitor.update(read_bytes)
        out.append(monitor)
    return out


def monitor_totals(run: RunFiles) -> tuple[int, float | None]:
    """Steps and latest episode end (seconds since the epoch) over the run's monitor files (as far as read)."""
    files = monitor_files(run)
    ends = [f.last_end for f in files if f.last_end is not None and math.isfinite(f.last_end)]
    steps = sum(f.steps for f in files)
    return int(steps) if math.isfinite(steps) else 0, max(ends) if ends else None


def monitor_curve(run: RunFiles, notes: list[str], steps_per_env_step: float = 1.0,
                  max_points: int | None = None) -> dict[str, Any]:
    """Training episodes of every monitor file, ordered by end time: ``timesteps`` (cumulative monitor steps times
    ``steps_per_env_step``), ``returns``, ``lengths``, ``time`` (seconds since the run began), at most
    ``max_points`` (default :data:`MAX_POINTS`) of them, and ``episodes`` (how many there are in all)."""
    max_points = MAX_POINTS if max_points is None else max_points
    kept, starts = [], []
    episodes = 0
    for monitor in monitor_files(run):
        data, t_start, file_notes = monitor.snapshot()
        notes += file_notes
        episodes += monitor.episodes
        kept.append(data)
        if t_start is not None:
            starts.append(t_start)
    merged = {k: np.concatenate([d[k] for d in kept]) if kept else np.empty(0) for k in _FIELDS}
    order = np.lexsort((merged["length"], merged["ret"], merged["end"]))
    merged = {k: v[order] for k, v in merged.items()}
    pick = np.unique(np.linspace(0, len(order) - 1, max_points).astype(np.int64)) if len(order) > max_points \
        else slice(None)
    with np.errstate(over="ignore"):
        timesteps = np.cumsum(merged["steps"]) * steps_per_env_step
        time = merged["end"][pick] - (min(starts) if starts else 0.0)
    return {
        "timesteps": timesteps[pick].tolist(),
        "returns": merged["ret"][pick].tolist(),
        "lengths": merged["length"][pick].tolist(),
        "time": time.tolist(),
        "episodes": episodes,
    }
