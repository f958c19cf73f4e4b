"""The over-seeds table the learning sections share: per-seed values, mean +- std and the IQM with its 95% interval.

The figures are :func:`benchmarks.stats.seed_stats` dictionaries stored in the results when a benchmark runs;
this module only formats them (no rliable needed to render).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from benchmarks.stats import seed_stats, stats_columns

#: One row of the over-seeds table: (group label, metric label, seed_stats figures, number format).
StatsRow = tuple[str, str, dict[str, Any], str]


def iqm_note(n_seeds: int) -> str:
    """The sentence that says what the IQM column is (``n_seeds``: the most seeds a row has)."""
    wide = f"; with {n_seeds} seeds the interval is wide" if n_seeds <= 3 else ""
    return ("Over seeds: the per-seed values, their mean +- sample standard deviation and the interquartile mean "
            "(IQM) with its 95% interval (rliable's `aggregate_iqm`, stratified bootstrap percentile interval over "
            f"{n_seeds} seeds{wide}); a row of 1 seed shows no interval.")


def stats_of(values: Sequence[float]) -> dict[str, Any]:
    """:func:`benchmarks.stats.seed_stats` of one metric's per-seed values."""
    return seed_stats(values)


def stats_table(head: str, rows: Sequence[StatsRow]) -> list[str]:
    """The Markdown lines of the over-seeds table: its note, a blank line and the table."""
    n_seeds = max((stats["n"] for _, _, stats, _ in rows), default=1)
    lines = [iqm_note(n_seeds), "", f"| {head} | metric | seeds | per seed | mean +- std | IQM [95% CI] |",
             "|---|---|---:|---|---:|---:|"]
    for label, metric, stats, fmt in rows:
        per_seed, mean_std, iqm = stats_columns(stats, fmt)
        if stats["n"] == 1:
            mean_std, iqm = f"{stats['mean']:{fmt}}", "1 seed"
        lines.append(f"| {label} | {metric} | {stats['n']} | {per_seed} | {mean_std} | {iqm} |")
    return lines
