"""EpCost over training: the cost and violations of every finished episode of a transparency log, read
incrementally (each call reads at most ``byte_budget`` new bytes, so a big log is summed over a few polls and a
growing one only from where the last call stopped). ``.csv.gz`` logs are decompressed as a stream across calls,
including the several gzip members an appended log has and a member still being written (the paging's
:class:`~sbagents.dashboard.logsources.GzCursor`)."""

from __future__ import annotations

import contextlib
import csv
import os
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from sbagents.dashboard.folders import open_regular
from sbagents.dashboard.logsources import BoundedLines, GzCheckpoint, GzCursor

#: Bytes read per call (plain CSV) or compressed bytes (gzip).
BYTE_BUDGET = 32 << 20
#: A line longer than this is skipped (a header this long: the file is not a log, and is not read further).
MAX_LINE_BYTES = 1 << 20
#: Episodes unfinished at once beyond which the file is not read further (a log has one per env and agent).
MAX_OPEN_EPISODES = 1 << 16


@dataclass
class _Episode:
    cost: float = 0.0
    violations: int = 0
    steps: int = 0


@dataclass
class EpisodeCosts:
    """Per-episode cost sums of one log; call :meth:`update` to read what was appended since the last call."""

    path: Path
    offset: int = 0
    header: list[str] | None = None
    lines_in: BoundedLines = field(default_factory=lambda: BoundedLines(MAX_LINE_BYTES))
    episodes: dict[tuple[str, str], _Episode] = field(default_factory=dict)
    finished: list[_Episode] = field(default_factory=list)
    _gz: GzCursor | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock)
    inode: int | None = None
    problem: str | None = None  #: why the log is not read (further)

    def update(self, byte_budget: int = BYTE_BUDGET) -> dict[str, Any]:
        """Read up to ``byte_budget`` new bytes; return ``episodes`` (index of each finished episode in order of
        ending), ``ep_cost``, ``violations``, ``lengths``, ``has_cost``, ``progress`` (share of the file read) and
        ``problem`` (None, or why the log is not read)."""
        with self._lock:
            try:
                with open_regular(self.path) as fh:
                    st = os.fstat(fh.fileno())
                    size = st.st_size
                    if size < self.offset or st.st_ino != self.inode:  # replaced: start over
                        self._reset()
                        self.inode = st.st_ino
                    if self.problem is not None:
                        data = b""
                    else:
                        gz = self.path.suffix == ".gz"
                        data = self._read_gz(fh, byte_budget) if gz else self._read(fh, byte_budget)
            except OSError:
                data, size = b"", max(self.offset, 1)
            self._consume(data)
            return self._result(1.0 if self.problem else self.offset / max(size, 1))

    def _reset(self) -> None:
        self.offset, self.header, self.lines_in, self._gz = 0, None, BoundedLines(MAX_LINE_BYTES), None
        self.episodes, self.finished = {}, []
        self.problem = None

    def _read(self, fh: IO[bytes], byte_budget: int) -> bytes:
        fh.seek(self.offset)
        raw = fh.read(byte_budget)
        self.offset += len(raw)
        return raw

    def _read_gz(self, fh: IO[bytes], byte_budget: int) -> bytes:
        """Decompressed bytes of about ``byte_budget`` more compressed bytes (stops at an unfinished member)."""
        if self._gz is None:
            self._gz = GzCursor(GzCheckpoint(0, None, 0))
        out: list[bytes] = []
        while self._gz.comp - self.offset < byte_budget and (chunk := self._gz.step(fh)) is not None:
            out.append(chunk)
        self.offset = self._gz.comp
        return b"".join(out)

    def _consume(self, data: bytes) -> None:
        block, dropped = self.lines_in.feed(data)
        if dropped and self.header is None:
            self.problem = f"{self.path.name}: its first line is over {MAX_LINE_BYTES:,} bytes (not a log)"
        lines = block.decode("utf-8", errors="replace").replace("\x00", "").splitlines()
        if not lines:
            return
        reader = _tolerant_rows(lines)
        if self.header is None:
            self.header = next(reader, None)
        cols = {name.lower(): i for i, name in enumerate(self.header or [])}
        ep_i, env_i = cols.get("episode"), cols.get("env")
        cost_i, viol_i = cols.get("cost"), cols.get("violation")
        done_i = [cols[c] for c in ("terminated", "truncated", "done") if c in cols]
        if ep_i is None:
            return
        for row in reader:
            if len(row) != len(self.header or []):
                continue
            key = (row[env_i] if env_i is not None else "0", row[ep_i])
            episode = self.episodes.get(key)
            if episode is None:
                if len(self.episodes) >= MAX_OPEN_EPISODES:
                    self.problem = (f"{self.path.name}: over {MAX_OPEN_EPISODES:,} episodes unfinished at once "
                                    "(not a transparency log?); read no further")
                    return
                episode = self.episodes[key] = _Episode()
            episode.steps += 1
            violated = bool(viol_i is not None and row[viol_i])
            episode.violations += violated
            with contextlib.suppress(ValueError):
                episode.cost += float(row[cost_i]) if cost_i is not None and row[cost_i] else float(violated)
            if any(row[i] in ("True", "true", "1") for i in done_i):
                self.finished.append(self.episodes.pop(key))

    def _result(self, progress: float) -> dict[str, Any]:
        cols = {name.lower() for name in self.header or []}
        eps = self.finished
        return {
            "episodes": list(range(len(eps))),
            "ep_cost": [e.cost for e in eps],
            "violations": [e.violations for e in eps],
            "lengths": [e.steps for e in eps],
            "has_cost": bool({"cost", "violation"} & cols),
            "progress": min(progress, 1.0),
            "problem": self.problem,
        }


def _tolerant_rows(lines: list[str]) -> Iterator[list[str]]:
    """``csv.reader`` rows of ``lines``, a line it rejects (an over-long quoted field) split at commas."""
    for line in lines:
        try:
            yield from csv.reader([line])
        except csv.Error:
            yield line.split(",")


_CACHE: dict[Path, EpisodeCosts] = {}
_CACHE_LOCK = threading.Lock()


def episode_costs(path: Path) -> dict[str, Any]:
    """The EpCost series of the log at ``path`` (a real path under a served folder; one reader per file and
    process, continued on every call)."""
    with _CACHE_LOCK:
        reader = _CACHE.setdefault(path, EpisodeCosts(path))
    return reader.update()
