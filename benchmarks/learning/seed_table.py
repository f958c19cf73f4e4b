"""What the learning sections share: the per-seed statistics table and the sentence that explains it.

A learning benchmark stores :func:`benchmarks.stats.seed_stats` of each metric in its results when it runs
(``results["stats"][metric]``); its section shows them with :func:`stats_table` and :func:`iqm_note`, which only
format the stored figures (no rliable, no bootstrap at render time).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from benchmarks.stats import stats_columns

#: One row of :func:`stats_table`: (label, key in ``stats``, format of the numbers).
StatRow = tuple[str, str, str]
#: Metrics where less is better (training time); recorded with their figures.
LOWER_IS_BETTER: frozenset[str] = frozenset({"train_seconds", "train_s"})


def metric_stats(values: Mapping[str, Sequence[float]]) -> dict[str, dict[str, Any]]:
    """:func:`benchmarks.stats.seed_stats` of each metric's per-seed values (needs rliable)."""
    from benchmarks.stats import seed_stats

    return {key: seed_stats(vals, higher_is_better=key not in LOWER_IS_BETTER) for key, vals in values.items()}


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
    """The sentence under a statistics table: what the IQM and its interval are, for ``n_seeds`` seeds."""
    if n_seeds < 2:
        return "1 seed: the value of that run, no mean, spread or interval."
    return (f"{n_seeds} seeds. IQM: interquartile mean over the seeds (rliable's `aggregate_iqm`); the interval is "
            f"its 95% stratified bootstrap percentile interval (rliable, seeded, so it renders the same every time). "
            f"With {n_seeds} seeds the interval is wide: it can only span the seeds' own values.")
