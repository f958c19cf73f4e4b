"""What the learning sections share: the per-seed statistics table and the sentence that explains it.

A learning benchmark stores :func:`benchmarks.stats.seed_stats` of each metric in its results when it runs
(``results["stats"][metric]``, through :func:`metric_stats` or :func:`stats_of`); its section shows them with
:func:`stats_table` (one row per metric) or :func:`grouped_stats_table` (rows of several groups: methods, variants,
opponents) and :func:`iqm_note`, which only format the stored figures (no rliable, no bootstrap at render time).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from benchmarks import stats as _stats
from benchmarks.stats import stats_columns

#: One row of :func:`stats_table`: (label, key in ``stats``, format of the numbers).
StatRow = tuple[str, str, str]
#: One row of :func:`grouped_stats_table`: (group label, metric label, seed_stats figures, number format).
StatsRow = tuple[str, str, dict[str, Any], str]
#: Metrics where less is better (training time); recorded with their figures.
LOWER_IS_BETTER: frozenset[str] = frozenset({"train_seconds", "train_s"})


def metric_stats(values: Mapping[str, Sequence[float]]) -> dict[str, dict[str, Any]]:
    """:func:`benchmarks.stats.seed_stats` of each metric's per-seed values (needs rliable)."""
    return {key: _stats.seed_stats(vals, higher_is_better=key not in LOWER_IS_BETTER) for key, vals in values.items()}


def stats_of(values: Sequence[float]) -> dict[str, Any]:
    """:func:`benchmarks.stats.seed_stats` of one metric's per-seed values (needs rliable)."""
    return _stats.seed_stats(values)


def stats_table(stats: dict[str, dict[str, Any]], rows: Sequence[StatRow]) -> list[str]:
    """Markdown lines of a table: metric, per-seed values, mean +- std, IQM [95% CI] (one row per ``rows`` entry
    whose key is in ``stats``). With one seed the last two cells are ``-``: there is no spread to show."""
    lines = ["| metric | per seed | mean +- std | IQM [95% CI] |", "|---|---:|---:|---:|"]
    for label, key, fmt in rows:
        if key not in stats:
            continue
        cells = stats_columns(stats[key], fmt)
        if stats[key]["n"] < 2:
            cells[1:] = ["-", "-"]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines


def iqm_note(n_seeds: int) -> str:
    """The sentence that says what the statistics are (``n_seeds``: the most seeds a row has)."""
    if n_seeds < 2:
        return "1 seed: the value of that run, no mean, spread or interval."
    wide = f"; with {n_seeds} seeds the interval is wide" if n_seeds <= 3 else ""
    return ("Over seeds: the per-seed values, their mean +- sample standard deviation and the interquartile mean "
            "(IQM) with its 95% interval (rliable's `aggregate_iqm`, stratified bootstrap percentile interval over "
            f"{n_seeds} seeds{wide}); a row of 1 seed shows no interval.")


def grouped_stats_table(head: str, rows: Sequence[StatsRow]) -> list[str]:
    """The Markdown lines of an over-seeds table with a group column: its note, a blank line and the table."""
    n_seeds = max((stats["n"] for _, _, stats, _ in rows), default=1)
    lines = [iqm_note(n_seeds), "", f"| {head} | metric | seeds | per seed | mean +- std | IQM [95% CI] |",
             "|---|---|---:|---|---:|---:|"]
    for label, metric, stats, fmt in rows:
        per_seed, mean_std, iqm = stats_columns(stats, fmt)
        if stats["n"] == 1:
            mean_std, iqm = f"{stats['mean']:{fmt}}", "1 seed"
        lines.append(f"| {label} | {metric} | {stats['n']} | {per_seed} | {mean_std} | {iqm} |")
    return lines
