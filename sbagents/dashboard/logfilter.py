"""Row filters of :class:`sbagents.dashboard.logindex.LogIndex`: :class:`RowFilter`, parsing and matching blocks.

A filtered query reads the log block by block (``block_rows`` rows). A block without quotes whose every line has
the header's number of fields (nearly every block of a transparency log) is not parsed row by row
(:class:`_SplitBlock`): numpy locates every field's start and end, integers are read from their digits, emptiness
of ``violation`` is a length, and only the filtered columns and the matching rows are decoded. Other blocks are
parsed with the ``csv`` module (:class:`_ParsedBlock`). A block read whole leaves a summary (:class:`_Summary`:
min/max episode, env, step and reward, its agents, whether any row is a violation), and later queries skip blocks
that provably hold no match (:func:`_skippable`).
"""

from __future__ import annotations

import csv
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: Distinct agents remembered per block summary (more: the block is never skipped on ``agent``).
MAX_SUMMARY_AGENTS = 64


@dataclass
class RowFilter:
    """Which rows a :meth:`LogIndex.query` returns; every given field must hold (an empty filter matches all).

    Column names are looked up as written by the callback and in the book's capitalised layout
    (``episode``/``Episode``, ...). A filter on a column the log does not have matches no row; so does a cell
    that does not parse as a number for a numeric field.
    """

    episode: int | None = None  #: value of the ``episode`` column
    env: int | None = None  #: value of the ``env`` column
    agent: str | None = None  #: value of the ``agent`` column (multi-agent logs)
    step_min: int | None = None  #: inclusive lower bound of ``step``
    step_max: int | None = None  #: inclusive upper bound of ``step``
    reward_min: float | None = None  #: inclusive lower bound of ``reward``
    reward_max: float | None = None  #: inclusive upper bound of ``reward``
    #: rows whose ``violation`` cell is non-empty or whose ``cost`` is > 0 (no such column: no row matches)
    violations_only: bool = False

    def is_empty(self) -> bool:
        """True when no field is set (every row matches)."""
        return (
            self.episode is None
            and self.env is None
            and self.agent is None
            and self.step_min is None
            and self.step_max is None
            and self.reward_min is None
            and self.reward_max is None
            and not self.violations_only
        )


@dataclass
class _Summary:
    """What a fully parsed block holds: ranges (``(inf, -inf)`` when no cell parses), agents, violations."""

    ranges: dict[str, tuple[float, float]]
    agents: frozenset[str] | None
    any_violation: bool
    rows: int


def _parse_lines(data: bytes, n_cols: int) -> list[list[str]]:
    """One list of cells per line of ``data`` (complete lines), as ``csv.reader`` parses each line on its own.

    Lines without quotes or carriage returns (nearly all of a transparency log) are split at commas, which is
    what ``csv.reader`` does with them, about twice as fast.
    """
    text = data.decode("utf-8", "replace").split("\n")
    if text and text[-1] == "":
        text.pop()
    if b'"' not in data and b"\r" not in data:
        rows = [line.split(",") for line in text]
    else:
        try:
            rows = list(csv.reader(text))
        except csv.Error:  # a stray carriage return, an over-long quoted field: line by line below
            rows = []
        if len(rows) != len(text):  # an unclosed quote joined lines (or csv failed): parse them one by one
            rows = [_parse_line(t) for t in text]
    for r in rows:
        if len(r) < n_cols:
            r.extend([""] * (n_cols - len(r)))
    return rows


def _parse_line(line: str) -> list[str]:
    """One line's cells as ``csv.reader`` parses it; split at commas when it refuses the line."""
    try:
        return next(csv.reader([line.replace("\x00", "")]), [])
    except csv.Error:
        return line.split(",")


def _numbers(cells: list[str]) -> np.ndarray:
    """Cells as float64; NaN where a cell does not parse."""
    try:
        return np.asarray(cells, dtype=np.float64)
    except ValueError:
        out = np.empty(len(cells))
        for i, c in enumerate(cells):
            try:
                out[i] = float(c)
            except ValueError:
                out[i] = np.nan
        return out


class _ParsedBlock:
    """The rows of a block parsed into cells (any block; the slow path)."""

    def __init__(self, rows: list[list[str]]) -> None:
        self.rows = rows
        self.n = len(rows)

    def numbers(self, col: int) -> np.ndarray:
        return _numbers([r[col] for r in self.rows])

    def strings(self, col: int) -> list[str]:
        return [r[col] for r in self.rows]

    def nonempty(self, col: int) -> np.ndarray:
        return np.fromiter((r[col] != "" for r in self.rows), dtype=bool, count=self.n)

    def take(self, indices: list[int]) -> list[list[str]]:
        return [self.rows[i] for i in indices]


class _SplitBlock:
    """A block without quotes or carriage returns whose every line has the header's number of fields: cells are
    located with numpy (start and end offset of every field) and only the cells a filter needs are decoded."""

    def __init__(self, data: bytes, b: np.ndarray, seps: np.ndarray, n_cols: int) -> None:
        self.data, self.b, self.n_cols = data, b, n_cols
        self.ends = seps.reshape(-1, n_cols)
        self.n = self.ends.shape[0]
        self.starts = np.empty_like(self.ends)
        self.starts[:, 1:] = self.ends[:, :-1] + 1
        self.starts[0, 0] = 0
        self.starts[1:, 0] = self.ends[:-1, -1] + 1

    @staticmethod
    def make(data: bytes, n_rows: int, n_cols: int) -> _SplitBlock | None:
        if n_cols == 0 or b'"' in data or b"\r" in data:
            return None
        b = np.frombuffer(data, np.uint8)
        newline = b == 10
        seps = np.flatnonzero(newline | (b == 44))
        if seps.size != n_rows * n_cols or not newline[seps[n_cols - 1 :: n_cols]].all():
            return None
        return _SplitBlock(data, b, seps, n_cols)

    def _cells(self, col: int) -> list[bytes]:
        data = self.data
        return [data[s:e] for s, e in zip(self.starts[:, col].tolist(), self.ends[:, col].tolist(), strict=True)]

    def numbers(self, col: int) -> np.ndarray:
        starts, ends = self.starts[:, col], self.ends[:, col]
        width = ends - starts
        if width.size and width.min() > 0 and width.max() <= 15:  # non-negative integers: digits, vectorized
            w = int(width.max())
            idx = np.minimum(starts[:, None] + np.arange(w), len(self.b) - 1)
            digits = self.b[idx].astype(np.int64) - 48
            valid = np.arange(w) < width[:, None]
            if ((digits >= 0) & (digits <= 9) | ~valid).all():
                power = 10 ** np.maximum(width[:, None] - 1 - np.arange(w), 0)
                return (np.where(valid, digits * power, 0)).sum(axis=1).astype(np.float64)  # type: ignore[no-any-return]
        cells = self._cells(col)
        try:
            return np.asarray(cells, dtype=np.bytes_).astype(np.float64)
        except ValueError:
            return _numbers([c.decode("utf-8", "replace") for c in cells])

    def strings(self, col: int) -> list[str]:
        return [c.decode("utf-8", "replace") for c in self._cells(col)]

    def nonempty(self, col: int) -> np.ndarray:
        return self.ends[:, col] > self.starts[:, col]  # type: ignore[no-any-return]

    def take(self, indices: list[int]) -> list[list[str]]:
        data = self.data
        out = []
        for i in indices:
            cells = data[int(self.starts[i, 0]) : int(self.ends[i, -1])].decode("utf-8", "replace").split(",")
            out.append(cells)
        return out


def _missing_column(flt: RowFilter, column: Callable[[str], int | None]) -> bool:
    """True when a filter field names a column the log lacks (then no row matches); ``column`` maps a column name
    to its index (None: no such column)."""
    needs = [("episode", flt.episode is not None), ("env", flt.env is not None), ("agent", flt.agent is not None),
             ("step", flt.step_min is not None or flt.step_max is not None),
             ("reward", flt.reward_min is not None or flt.reward_max is not None)]
    if any(wanted and column(name) is None for name, wanted in needs):
        return True
    return flt.violations_only and column("violation") is None and column("cost") is None


def _block_match(block: _ParsedBlock | _SplitBlock, flt: RowFilter, summarize: bool,
                 column: Callable[[str], int | None]) -> tuple[np.ndarray, _Summary | None]:
    """Mask of the rows of ``block`` matching ``flt`` and, if ``summarize``, the summary of these rows."""
    n = block.n
    mask = np.ones(n, dtype=bool)
    ranges: dict[str, tuple[float, float]] = {}
    bounds = {"episode": (flt.episode, flt.episode), "env": (flt.env, flt.env),
              "step": (flt.step_min, flt.step_max), "reward": (flt.reward_min, flt.reward_max)}
    for name, (lo, hi) in bounds.items():
        idx = column(name)
        if idx is None or (lo is None and hi is None and not summarize):
            continue
        vals = block.numbers(idx)
        if summarize:
            good = vals[~np.isnan(vals)]
            ranges[name] = (float(good.min()), float(good.max())) if good.size else (np.inf, -np.inf)
        if lo is not None:
            mask &= vals >= lo
        if hi is not None:
            mask &= vals <= hi
    agents: frozenset[str] | None = None
    a_idx = column("agent")
    if a_idx is not None and (flt.agent is not None or summarize):
        cells = block.strings(a_idx)
        if flt.agent is not None:
            mask &= np.fromiter((c == flt.agent for c in cells), dtype=bool, count=n)
        if summarize:
            distinct = frozenset(cells)
            agents = distinct if len(distinct) <= MAX_SUMMARY_AGENTS else None
    violation = np.zeros(n, dtype=bool)
    if flt.violations_only or summarize:
        v_idx, c_idx = column("violation"), column("cost")
        if v_idx is not None:
            violation |= block.nonempty(v_idx)
        if c_idx is not None:
            violation |= block.numbers(c_idx) > 0
        if flt.violations_only:
            mask &= violation
    summary = _Summary(ranges, agents, bool(violation.any()), n) if summarize else None
    return mask, summary


def _skippable(s: _Summary, flt: RowFilter) -> bool:
    """True when the summarized block provably holds no row matching ``flt``."""

    def outside(name: str, lo: float | None, hi: float | None) -> bool:
        if name not in s.ranges or (lo is None and hi is None):
            return False
        b_lo, b_hi = s.ranges[name]
        return (lo is not None and b_hi < lo) or (hi is not None and b_lo > hi)

    return (
        outside("episode", flt.episode, flt.episode)
        or outside("env", flt.env, flt.env)
        or outside("step", flt.step_min, flt.step_max)
        or outside("reward", flt.reward_min, flt.reward_max)
        or (flt.agent is not None and s.agents is not None and flt.agent not in s.agents)
        or (flt.violations_only and not s.any_violation)
    )
