"""Statistics for learning results over seeds: mean +- std, the interquartile mean and 95% bootstrap intervals.

The IQM and its interval come from ``rliable`` (Agarwal et al., 2021: "Deep RL at the Edge of the Statistical
Precipice"), the library RL papers use for this: ``aggregate_iqm`` with stratified bootstrap percentile
intervals (``get_interval_estimates``). rliable's bootstrap draws its indices from NumPy's global generator even
when a ``random_state`` is given, so :func:`seed_stats` seeds that generator itself (and restores it afterwards):
the same values always give the same interval, which keeps rendered sections byte-stable.

The figures are computed when a benchmark runs and stored in its results file; rendering only formats them,
so ``render`` needs neither rliable nor the bootstrap. Install rliable with ``pip install -e ".[bench]"``.
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from typing import Any

#: Bootstrap resamples and the generator seed of :func:`seed_stats`.
BOOTSTRAP_REPS = 20_000
BOOTSTRAP_SEED = 0


def seed_stats(values: Sequence[float], *, reps: int = BOOTSTRAP_REPS, seed: int = BOOTSTRAP_SEED,
               higher_is_better: bool = True) -> dict[str, Any]:
    """Summary of one metric measured once per seed.

    :param values: one value per training seed, shape ``(n_seeds,)``.
    :param reps: bootstrap resamples for the interval.
    :param seed: seed of the bootstrap's generator.
    :param higher_is_better: recorded with the figures (renderers may order by it); no effect on the numbers.
    :return: ``{"n", "values", "mean", "std", "min", "max", "iqm", "iqm_ci": [low, high], "ci_level": 0.95,
        "method"}``; ``std`` is the sample standard deviation (0 for one seed). With one seed the interval is
        the value itself.
    """
    import numpy as np
    from rliable import library as rly
    from rliable import metrics

    vals = [float(v) for v in values]
    if not vals:
        raise ValueError("seed_stats needs at least one value")
    scores = np.asarray(vals, dtype=np.float64).reshape(-1, 1)  # (runs, tasks=1), rliable's layout
    state = np.random.get_state()
    np.random.seed(seed)
    try:
        point, intervals = rly.get_interval_estimates({"x": scores}, lambda s: np.array([metrics.aggregate_iqm(s)]),
                                                      reps=reps)
    finally:
        np.random.set_state(state)
    low, high = (float(v) for v in intervals["x"][:, 0])
    return {
        "n": len(vals),
        "values": vals,
        "mean": statistics.fmean(vals),
        "std": statistics.stdev(vals) if len(vals) > 1 else 0.0,
        "min": min(vals),
        "max": max(vals),
        "iqm": float(point["x"][0]),
        "iqm_ci": [low, high],
        "ci_level": 0.95,
        "method": f"rliable aggregate_iqm, stratified bootstrap percentile interval, {reps} reps, seed {seed}",
        "higher_is_better": higher_is_better,
    }


def format_iqm(stats: dict[str, Any], fmt: str = ".2f") -> str:
    """``"IQM [low, high]"`` of :func:`seed_stats`' figures, e.g. ``"4.80 [4.75, 4.90]"``."""
    low, high = stats["iqm_ci"]
    return f"{stats['iqm']:{fmt}} [{low:{fmt}}, {high:{fmt}}]"


def format_mean_std(stats: dict[str, Any], fmt: str = ".2f") -> str:
    """``"mean +- std"`` of :func:`seed_stats`' figures, e.g. ``"4.82 +- 0.08"``."""
    return f"{stats['mean']:{fmt}} +- {stats['std']:{fmt}}"


#: The sentence under a table of :func:`format_iqm` figures.
IQM_NOTE = "IQM: the interquartile mean; brackets: its 95% stratified bootstrap interval (rliable)."


def stats_bullets(stats: dict[str, dict[str, Any]], what: str, fmt: str = ".2f") -> list[str]:
    """One line per row of ``stats`` (name -> :func:`seed_stats`' figures): ``- name: <what> mean +- std over n
    seed(s), IQM [low, high].`` (no IQM for 1 seed), then a blank line and :data:`IQM_NOTE`."""
    lines = []
    for name, st in stats.items():
        interval = f", IQM {format_iqm(st, fmt)}" if st["n"] > 1 else ""
        lines.append(f"- {name}: {what} {format_mean_std(st, fmt)} over {st['n']} seed(s){interval}.")
    return [*lines, "", IQM_NOTE]


def stats_columns(stats: dict[str, Any], fmt: str = ".2f") -> list[str]:
    """The three cells learning tables show for a metric over seeds: per-seed values, mean +- std, IQM [95% CI]."""
    return [" / ".join(f"{v:{fmt}}" for v in stats["values"]), format_mean_std(stats, fmt), format_iqm(stats, fmt)]
