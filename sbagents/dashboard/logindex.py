"""Paging engine for transparency logs: random access to the rows of a (growing) CSV or CSV.gz file.

A transparency log (:class:`sbagents.callbacks.TransparencyCSVCallback`) is a header line and one row per
decision; it can grow to gigabytes and is appended to while training runs. :class:`LogIndex` never loads the
file: it scans it in chunks, finds newlines with numpy and records the byte offset of every ``block_rows``-th
row. A page seeks to the nearest recorded row and reads forward, so ``page(0, n)`` needs only the first chunk
and a page deep in the file needs the index only as far as that page. :meth:`LogIndex.refresh` extends the
index (all of it, or for a time budget, from a background thread); every public method is thread-safe.

- **Plain CSV** and **CSV.gz**: offsets are file offsets, resp. offsets in the uncompressed stream; reading
  ranges, the gzip checkpoints and the on-disk index cache (plain CSV only) are in
  :mod:`sbagents.dashboard.logsources`.
- **Filtered queries** (:meth:`LogIndex.query`, :meth:`LogIndex.episode_rows`) read block by block, for a time
  budget, and return the row to continue from. Parsing and matching blocks, and the block summaries that let
  later queries skip blocks, are in :mod:`sbagents.dashboard.logfilter` (with :class:`RowFilter`).

Limitations: rows are split at newline bytes. The writer quotes a field with a newline (info strings), which
essentially never happens; such a row shows as two rows, each parsed on its own. A file that replaced the log
(smaller, or another inode) is re-indexed from scratch by :meth:`LogIndex.refresh` (and by
:func:`sbagents.dashboard.logregistry.open_log`, which shares one index per file). A first line over
:data:`MAX_HEADER_BYTES` makes the file no log (:attr:`LogIndex.problem`): no more of it is read.
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sbagents.dashboard.folders import open_regular
from sbagents.dashboard.logfilter import (
    RowFilter,
    _block_match,
    _missing_column,
    _parse_line,
    _parse_lines,
    _ParsedBlock,
    _skippable,
    _SplitBlock,
    _Summary,
)
from sbagents.dashboard.logsources import (
    GzCheckpoint,
    _cache_file,
    _GzScanner,
    _load_index_cache,
    _RangeReader,
    _save_index_cache,
)

#: Bytes (uncompressed) scanned per step once the scan is under way; the first step scans
#: :data:`FIRST_STEP_BYTES` and each next one twice as many, so a first page costs one small read.
CHUNK_BYTES = 16 << 20
FIRST_STEP_BYTES = 1 << 20
#: Seconds between two writes of the on-disk cache while a growing file is re-indexed.
CACHE_SAVE_INTERVAL = 5.0
#: A first line (the header) longer than this: the file is not a log, and nothing more of it is read.
MAX_HEADER_BYTES = 1 << 20


@dataclass
class Page:
    """Rows of a log and what is known of the file."""

    columns: list[str]
    rows: list[list[str]]  #: cells as ``csv.reader`` parses them
    row_numbers: list[int]  #: 0-based data-row numbers in the file (the header is not a row)
    total_rows: int  #: complete rows indexed so far
    complete: bool  #: the index covers the whole file as it is now
    next_cursor: int | None  #: row to continue from (None: nothing after this page, as far as the file goes now)
    scanned_to: int  #: rows scanned (filtered queries) or read (pages) so far


class LogIndex:
    """Row index of one CSV/CSV.gz log by byte offset (every ``block_rows``-th row), built incrementally.

    :param path: the log (``.gz``: gzip, else plain CSV). It is only read.
    :param block_rows: rows per index block (a page reads from the block start before it).
    :param resolved: ``path`` is already a real path (the dashboard's, from
        :meth:`~sbagents.dashboard.folders.RunFiles.file`) and is not resolved again: every read opens it without
        following any symlink, so one swapped in since it was checked is refused rather than followed out of the
        served folder. False: symlinks in ``path`` are resolved once, here.
    """

    def __init__(self, path: Path, block_rows: int = 1024, resolved: bool = False) -> None:
        if block_rows < 1:
            raise ValueError(f"block_rows must be >= 1, got {block_rows}")
        self.gzip = Path(path).name.endswith(".gz")
        self.path = Path(os.path.abspath(path)) if resolved else Path(path).resolve()
        self.block_rows = int(block_rows)
        self._lock = threading.RLock()
        #: bytes (uncompressed) this object has scanned for newlines; a cached index scans only the new tail
        self.bytes_scanned = 0
        #: True when the index came from the on-disk cache
        self.cache_loaded = False
        self._cache_path = _cache_file(self.path, self.block_rows)
        self._last_save = 0.0
        self._saved_rows = -1
        self._reset()
        if not self.gzip:
            self._load_cache()
        with self._lock:  # the header (columns) is known from the start: the first chunk is scanned
            while self._header_end is None and self._scan_step():
                pass

    # ------------------------------------------------------------------ state
    def _reset(self) -> None:
        st = os.lstat(self.path)
        self._inode = st.st_ino
        self.columns: list[str] = []
        self._col: dict[str, int] = {}
        self._header_end: int | None = None
        self._head = b""
        self._offsets: list[int] = []  # uncompressed offset of row k * block_rows
        self._rows = 0  # complete rows seen
        self._row_end = 0  # offset after the last complete row (or after the header)
        self._read_pos = 0  # plain: file bytes examined
        self._complete = False
        self._step_bytes = FIRST_STEP_BYTES
        self._summaries: dict[int, _Summary] = {}
        #: why the file is not read as a log (its first line is over :data:`MAX_HEADER_BYTES`), None when it is one
        self.problem: str | None = None
        self._gz: _GzScanner | None = _GzScanner() if self.gzip else None
        #: where a ``.gz`` log can be decompressed from (the scanner's list: it appends to it)
        self._checkpoints: list[GzCheckpoint] = self._gz.checkpoints if self._gz is not None else []

    def _known_size(self) -> int:
        """Bytes of the file already examined (compressed bytes for ``.gz``)."""
        if self._gz is not None:
            return self._gz.known_size()
        return self._read_pos

    def _stale(self, st: os.stat_result) -> bool:
        return st.st_ino != self._inode or st.st_size < self._known_size()

    def is_stale(self) -> bool:
        """True when the file was replaced or truncated since it was indexed (or is gone)."""
        try:
            st = os.lstat(self.path)  # a real path: a symlink there was swapped in (then stale)
        except OSError:
            return True
        with self._lock:
            return self._stale(st)

    def _set_header(self, line: bytes) -> None:
        text = line.decode("utf-8", "replace").rstrip("\r\n")
        self.columns = _parse_line(text)
        self._col = {}
        for i, name in enumerate(self.columns):
            self._col.setdefault(name, i)

    def column(self, name: str) -> int | None:
        """Index of column ``name`` (``episode``: also ``Episode``), None when the log has none."""
        for cand in (name, name.capitalize()):
            if cand in self._col:
                return self._col[cand]
        return None

    # ------------------------------------------------------------------ scanning
    def _consume(self, base: int, data: bytes) -> None:
        """Index ``data``, the uncompressed bytes at offset ``base`` that follow everything consumed so far."""
        self.bytes_scanned += len(data)
        if self._header_end is None:
            searched = len(self._head)
            self._head += data[: MAX_HEADER_BYTES + 1 - searched]
            cut = self._head.find(b"\n", searched)
            if cut < 0:
                if len(self._head) > MAX_HEADER_BYTES:
                    self.problem = f"{self.path.name}: its first line is over {MAX_HEADER_BYTES:,} bytes (not a log)"
                    self._head = b""
                return
            self._set_header(self._head[:cut])
            self._header_end = self._row_end = cut + 1
            self._offsets = [cut + 1]
            skip = cut + 1 - base
            self._head = b""
            data, base = data[skip:], base + skip
        if not data:
            return
        nl = np.flatnonzero(np.frombuffer(data, np.uint8) == 10)
        if nl.size == 0:
            return
        starts = nl + (base + 1)  # start of the row after each newline
        first = self._rows + 1  # row number starting at starts[0]
        self._offsets.extend(starts[(-first) % self.block_rows :: self.block_rows].tolist())
        self._rows += int(nl.size)
        self._row_end = int(starts[-1])

    def _scan_step(self) -> bool:
        """Index one more chunk (call with the lock held); False when the file has nothing more now."""
        if self.problem is not None:
            self._complete = True
            return False
        if self._gz is not None:
            produced, ended = self._gz.scan(self.path, self._step_bytes, CHUNK_BYTES, self._consume)
            if ended:
                self._complete = True
                return produced > 0
            self._step_bytes = min(self._step_bytes * 2, CHUNK_BYTES)
            self._complete = False
            return True
        with open_regular(self.path) as fh:
            fh.seek(self._read_pos)
            data = fh.read(self._step_bytes)
        self._step_bytes = min(self._step_bytes * 2, CHUNK_BYTES)
        if not data:
            self._complete = True
            self._maybe_save()
            return False
        self._consume(self._read_pos, data)
        self._read_pos += len(data)
        self._complete = False
        return True

    def _check_file(self) -> None:
        """Re-index from scratch when the file was replaced or truncated (lock held)."""
        try:
            st = os.lstat(self.path)
        except OSError:
            return
        if self._stale(st):
            self._reset()
        elif self._complete and self.problem is None and st.st_size > self._known_size():
            self._complete = False

    def _ensure_rows(self, n: int, deadline: float | None = None) -> None:
        """Index until ``n`` rows are known, the file ends or ``deadline`` (perf_counter) passes."""
        while True:
            with self._lock:
                if self._rows >= n:
                    return
                if self._complete:
                    self._check_file()  # the file may have grown (or been replaced) since the last scan
                    if self._complete:
                        return
                self._scan_step()
            if deadline is not None and time.perf_counter() > deadline:
                return

    def refresh(self, time_budget: float | None = None) -> None:
        """Index the bytes appended since the last call (all of the unindexed part, or ``time_budget`` seconds
        of work); a replaced or truncated file is re-indexed from the start."""
        deadline = None if time_budget is None else time.perf_counter() + time_budget
        with self._lock:
            self._check_file()
            self._complete = False
        while True:
            with self._lock:
                if not self._scan_step() and self._complete:
                    return
            if deadline is not None and time.perf_counter() > deadline:
                return

    @property
    def total_rows(self) -> int:
        """Complete rows indexed so far."""
        with self._lock:
            return self._rows

    @property
    def complete(self) -> bool:
        """True when the index covers the whole file as it was at the last scan."""
        with self._lock:
            return self._complete

    # ------------------------------------------------------------------ disk cache (plain CSV)
    def _load_cache(self) -> None:
        cached = _load_index_cache(self._cache_path, self.path, self.block_rows)
        if cached is None:
            return
        self._set_header(cached.header)
        self._header_end = cached.header_end
        self._offsets = cached.offsets
        self._rows = cached.rows
        self._row_end = self._read_pos = cached.scan_pos
        self._complete = cached.size == self._read_pos
        self._saved_rows = self._rows
        self.cache_loaded = True

    def _maybe_save(self) -> None:
        """Write the index of a plain CSV to the cache (lock held; throttled while the file grows)."""
        if self.gzip or self._header_end is None or self._rows == self._saved_rows:
            return
        now = time.monotonic()
        if self._saved_rows >= 0 and now - self._last_save < CACHE_SAVE_INTERVAL:
            return
        if _save_index_cache(self._cache_path, self.path, self.block_rows, self._offsets, self._rows, self._row_end,
                             self._header_end):
            self._saved_rows, self._last_save = self._rows, now

    # ------------------------------------------------------------------ reading
    def _reader(self) -> _RangeReader:
        with self._lock:
            cks = list(self._checkpoints) if self.gzip else None
        return _RangeReader(self.path, cks)

    def _read_rows(self, reader: _RangeReader, start: int, end: int) -> list[list[str]]:
        """Parsed rows ``[start, end)`` (``end`` <= rows indexed)."""
        if end <= start:
            return []
        b = self.block_rows
        with self._lock:
            lo = self._offsets[start // b]
            k_end = -(-end // b)
            hi = self._offsets[k_end] if k_end < len(self._offsets) and k_end * b <= self._rows else self._row_end
            n_cols = len(self.columns)
        data = reader.read(lo, hi)
        skip, take = start - (start // b) * b, end - start
        try:
            cut = 0
            for _ in range(skip):  # at most block_rows - 1 lines before the first wanted one
                cut = data.index(b"\n", cut) + 1
            stop = cut
            for _ in range(take):
                stop = data.index(b"\n", stop) + 1
        except ValueError:  # the file was replaced while we read it: the rows that are there
            lines = data.split(b"\n")[:-1][skip : skip + take]
            return _parse_lines(b"".join(line + b"\n" for line in lines), n_cols)
        return _parse_lines(data[cut:stop], n_cols)

    def _read_block(self, reader: _RangeReader, k: int, n_rows: int) -> _ParsedBlock | _SplitBlock:
        """The ``n_rows`` first rows of block ``k`` (all of them unless it is the last, growing block)."""
        b = self.block_rows
        with self._lock:
            lo = self._offsets[k]
            full = k + 1 < len(self._offsets) and (k + 1) * b <= self._rows and n_rows == b
            hi = self._offsets[k + 1] if full else None
            n_cols = len(self.columns)
        if hi is None:  # a partial block: find its end
            return _ParsedBlock(self._read_rows(reader, k * b, k * b + n_rows))
        data = reader.read(lo, hi)
        if data.count(b"\n") != n_rows:  # the file changed under the read
            return _ParsedBlock(self._read_rows(reader, k * b, k * b + n_rows))
        return _SplitBlock.make(data, n_rows, n_cols) or _ParsedBlock(_parse_lines(data, n_cols))

    def _page(self, rows: list[list[str]], numbers: list[int], next_cursor: int | None, scanned: int) -> Page:
        with self._lock:
            return Page(list(self.columns), rows, numbers, self._rows, self._complete, next_cursor, scanned)

    def page(self, start: int, count: int) -> Page:
        """Rows ``[start, start + count)``, clipped to the rows in the file (indexing just as far as needed)."""
        start, count = max(int(start), 0), max(int(count), 0)
        self._ensure_rows(start + count + 1)
        with self._lock:
            total, complete = self._rows, self._complete
        end = min(start + count, total)
        reader = self._reader()
        try:
            rows = self._read_rows(reader, start, end)
        finally:
            reader.close()
        more = end < total or not complete
        return self._page(rows, list(range(start, max(end, start))), end if more else None, max(end, start))

    def tail(self, count: int) -> Page:
        """The last ``count`` rows (indexes the whole file first)."""
        self.refresh()
        with self._lock:
            total = self._rows
        return self.page(max(total - max(int(count), 0), 0), count)

    # ------------------------------------------------------------------ filtering
    def _scan(self, flt: RowFilter, cursor: int, limit: int, deadline: float | None, episode_stop: bool) -> Page:
        b = self.block_rows
        pos = max(int(cursor), 0)
        self._ensure_rows(1)
        if _missing_column(flt, self.column) and self.columns:
            with self._lock:
                return self._page([], [], None, self._rows)
        rows_out: list[list[str]] = []
        numbers: list[int] = []
        found_episode = False
        reader = self._reader()
        try:
            while True:
                self._ensure_rows(pos + 1, deadline)
                with self._lock:
                    total, complete = self._rows, self._complete
                    summary = self._summaries.get(pos // b)
                if pos >= total:
                    if complete:
                        return self._page(rows_out, numbers, None, pos)
                    break  # the deadline passed while indexing
                k = pos // b
                block_end = min((k + 1) * b, total)
                if summary is not None and _skippable(summary, flt):
                    if episode_stop and found_episode and summary.ranges.get("episode", (0.0, 0.0))[0] > (
                        flt.episode or 0
                    ):
                        return self._page(rows_out, numbers, None, pos)
                    pos = block_end
                else:
                    full = block_end == (k + 1) * b
                    block = self._read_block(reader, k, block_end - k * b)
                    mask, new_summary = _block_match(block, flt, full and summary is None, self.column)
                    if new_summary is not None:
                        with self._lock:
                            self._summaries[k] = new_summary
                        summary = new_summary
                    hits = (np.flatnonzero(mask[pos - k * b :]) + (pos - k * b)).tolist()[: limit - len(rows_out)]
                    rows_out += block.take(hits)
                    numbers += [k * b + i for i in hits]
                    if len(rows_out) >= limit:
                        pos = numbers[-1] + 1
                        with self._lock:
                            done = pos >= self._rows and self._complete
                        return self._page(rows_out, numbers, None if done else pos, pos)
                    found_episode = found_episode or bool(mask.any())
                    pos = block_end
                    if (
                        episode_stop
                        and found_episode
                        and summary is not None
                        and summary.ranges.get("episode", (0.0, 0.0))[0] > (flt.episode or 0)
                    ):
                        return self._page(rows_out, numbers, None, pos)
                if deadline is not None and time.perf_counter() > deadline:
                    break
        finally:
            reader.close()
        return self._page(rows_out, numbers, pos, pos)

    def query(self, flt: RowFilter, cursor: int = 0, limit: int = 100, time_budget: float = 0.5) -> Page:
        """Up to ``limit`` rows from row ``cursor`` on that match ``flt``, scanning for at most ``time_budget``
        seconds (at least one block is scanned).

        ``next_cursor`` is the row to continue from (None once every row of the file as it is now was scanned);
        ``scanned_to`` the row the scan reached. Continuing from ``next_cursor`` until it is None returns exactly
        the rows a full scan returns. An empty filter pages from ``cursor``.
        """
        limit = max(int(limit), 1)
        if flt.is_empty():
            page = self.page(cursor, limit)
            return page
        return self._scan(flt, cursor, limit, time.perf_counter() + time_budget, episode_stop=False)

    def episode_rows(self, episode: int, env: int | None = None, agent: str | None = None,
                     max_rows: int = 5000) -> Page:
        """All rows of ``episode`` (of ``env`` / ``agent`` if given), at most ``max_rows`` (then ``next_cursor``
        says where to continue).

        Skips blocks whose summary excludes the episode, and stops after the episode's rows once a whole block
        holds only later episodes: the callback numbers episodes per env without ever going back (appending
        continues after the largest number), so no later row can belong to the episode.
        """
        flt = RowFilter(episode=episode, env=env, agent=agent)
        return self._scan(flt, 0, max(int(max_rows), 1), None, episode_stop=True)


__all__ = ["LogIndex", "Page", "RowFilter"]
