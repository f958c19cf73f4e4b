"""Success broken down by episode attributes (object scale x mass, user preferences): report + callback."""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecEnv

from sbagents.atomic import save_figure, write_csv
from sbagents.callbacks.common import PeriodicEvalCallback, env_attr, output_dir, split_keys
from sbagents.callbacks.episodes import EpisodeRecord
from sbagents.callbacks.rollout import as_vec_env, run_episodes, sync_normalization

FAIRNESS_CSV = "fairness.csv"
FAIRNESS_PNG = "fairness.png"
Range = tuple[float, float]


def wilson_interval(successes: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval (95% by default) of a binomial proportion; ``(nan, nan)`` when ``n == 0``."""
    if n == 0:
        return float("nan"), float("nan")
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def bucket_edges(values: Sequence[float], bins: int, value_range: Range | None = None) -> np.ndarray:
    """``bins + 1`` equal-width edges over ``value_range`` (else the observed min/max)."""
    if bins < 1:
        raise ValueError(f"bins must be >= 1, got {bins}")
    if value_range is None:
        lo, hi = (float(np.min(values)), float(np.max(values))) if len(values) else (0.0, 1.0)
    else:
        lo, hi = float(value_range[0]), float(value_range[1])
    if hi <= lo:
        hi = lo + 1e-9
    return np.linspace(lo, hi, bins + 1)


def _bucket(value: float, edges: np.ndarray) -> int:
    """Index of the bucket holding ``value``; values outside the edges go to the first/last bucket."""
    return int(np.clip(np.searchsorted(edges, value, side="right") - 1, 0, len(edges) - 2))


def fairness_from_episodes(
    episodes: Sequence[EpisodeRecord],
    keys: Sequence[str],
    bins: int = 3,
    ranges: Mapping[str, Range] | None = None,
) -> dict[str, Any]:
    """Group episodes by the buckets of their attributes (read from each episode's last ``info``).

    :return: ``keys``, ``bins``, ``edges`` (per key), ``metric`` (``success_rate``, or ``mean_return``
        when no episode reports ``is_success``), ``n_episodes``, ``buckets`` (one dict per bucket of the grid:
        ``index``, ``<key>_low``/``<key>_high``, ``n``, ``successes``, ``value`` (rate or mean return),
        ``ci_low``/``ci_high`` (Wilson 95% for rates, normal 95% for returns; NaN when empty)),
        ``worst`` / ``best`` (the non-empty buckets with the lowest / highest value), ``gap`` (max - min
        over non-empty buckets) and ``ratio`` (min / max, for rates).
    """
    keys = list(keys)
    if not keys:
        raise ValueError("fairness needs at least one attribute key")
    for key in keys:
        missing = [i for i, e in enumerate(episodes) if key not in e.info]
        if missing:
            known = ", ".join(sorted(episodes[missing[0]].info))
            raise ValueError(f"episode info has no attribute {key!r} (available: {known})")
    ranges = dict(ranges or {})
    values = {k: [float(e.info[k]) for e in episodes] for k in keys}
    edges = {k: bucket_edges(values[k], bins, ranges.get(k)) for k in keys}
    use_success = any(e.success is not None for e in episodes)
    groups: dict[tuple[int, ...], list[EpisodeRecord]] = {}
    for i, ep in enumerate(episodes):
        idx = tuple(_bucket(values[k][i], edges[k]) for k in keys)
        groups.setdefault(idx, []).append(ep)
    buckets = []
    for idx in itertools.product(range(bins), repeat=len(keys)):
        eps = groups.get(idx, [])
        row: dict[str, Any] = {"index": list(idx)}
        for k, j in zip(keys, idx, strict=True):
            row[f"{k}_low"], row[f"{k}_high"] = float(edges[k][j]), float(edges[k][j + 1])
        row["n"] = len(eps)
        if use_success:
            s = sum(bool(e.success) for e in eps)
            row["successes"] = s
            row["value"] = s / len(eps) if eps else float("nan")
            row["ci_low"], row["ci_high"] = wilson_interval(s, len(eps))
        else:
            rets = np.array([e.ret for e in eps])
            row["successes"] = None
            row["value"] = float(rets.mean()) if eps else float("nan")
            half = 1.96 * float(rets.std(ddof=1)) / math.sqrt(len(eps)) if len(eps) > 1 else float("nan")
            row["ci_low"], row["ci_high"] = row["value"] - half, row["value"] + half
        buckets.append(row)
    filled = [b for b in buckets if b["n"] > 0]
    worst = min(filled, key=lambda b: b["value"]) if filled else None
    best = max(filled, key=lambda b: b["value"]) if filled else None
    gap = float(best["value"] - worst["value"]) if worst and best else float("nan")
    ratio = float("nan")
    if use_success and worst and best and best["value"] > 0:
        ratio = float(worst["value"] / best["value"])
    return {
        "keys": keys,
        "bins": bins,
        "edges": {k: v.tolist() for k, v in edges.items()},
        "metric": "success_rate" if use_success else "mean_return",
        "n_episodes": len(episodes),
        "buckets": buckets,
        "worst": worst,
        "best": best,
        "gap": gap,
        "ratio": ratio,
    }


def write_fairness_csv(report: Mapping[str, Any], path: str | Path) -> Path:
    """One row per bucket: ``<key>_low``, ``<key>_high`` per key, ``n``, ``successes``, ``<metric>``,
    ``ci_low``, ``ci_high``."""
    keys, metric = report["keys"], report["metric"]
    fields = [f for k in keys for f in (f"{k}_low", f"{k}_high")]
    fields += ["n", "successes", metric, "ci_low", "ci_high"]
    write_csv(path, fields, ({**b, metric: b["value"]} for b in report["buckets"]))
    return Path(path)


def plot_fairness(report: Mapping[str, Any], path: str | Path) -> Path:
    """Bar chart with 95% intervals (one key, or more than two keys flattened) or a heatmap (two keys)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    keys, buckets, metric, bins = report["keys"], report["buckets"], report["metric"], report["bins"]
    fig = Figure(figsize=(6.5, 4.5), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()

    def label(b: Mapping[str, Any], k: str) -> str:
        return f"{b[f'{k}_low']:.3g}-{b[f'{k}_high']:.3g}"

    if len(keys) == 2:
        grid = np.full((bins, bins), np.nan)
        for b in buckets:
            grid[b["index"][0], b["index"][1]] = b["value"]
        rate = metric == "success_rate"
        im = ax.imshow(
            grid, origin="lower", cmap="RdYlGn", aspect="auto",
            vmin=0.0 if rate else None, vmax=1.0 if rate else None,
        )
        fig.colorbar(im, ax=ax, label=metric)
        for b in buckets:
            i, j = b["index"]
            text = "n=0" if b["n"] == 0 else f"{b['value']:.2f}\nn={b['n']}"
            ax.text(j, i, text, ha="center", va="center", fontsize=8)
        rows = [b for b in buckets if b["index"][1] == 0]
        cols = [b for b in buckets if b["index"][0] == 0]
        ax.set_yticks(range(bins), [label(b, keys[0]) for b in rows])
        ax.set_xticks(range(bins), [label(b, keys[1]) for b in cols])
        ax.set_ylabel(keys[0])
        ax.set_xlabel(keys[1])
    else:
        vals = np.array([b["value"] for b in buckets], dtype=float)
        low = np.nan_to_num(vals - np.array([b["ci_low"] for b in buckets], dtype=float))
        high = np.nan_to_num(np.array([b["ci_high"] for b in buckets], dtype=float) - vals)
        xs = np.arange(len(buckets))
        ax.bar(xs, np.nan_to_num(vals), yerr=[low, high], capsize=3, color="tab:blue")
        ax.set_xticks(xs, ["\n".join(label(b, k) for k in keys) for b in buckets], fontsize=7)
        ax.set_xlabel(" / ".join(keys))
        ax.set_ylabel(metric)
    ax.set_title(f"{metric} per bucket (gap {report['gap']:.3g}, {report['n_episodes']} episodes)")
    fig.tight_layout()
    save_figure(fig, path)
    return Path(path)


def _declared_ranges(
    venv: VecEnv, keys: Sequence[str], ranges: Mapping[str, Range] | None
) -> dict[str, Range]:
    declared = env_attr(venv, "attribute_ranges") or {}
    out = {k: tuple(declared[k]) for k in keys if k in declared}
    out.update(dict(ranges or {}))
    return out  # type: ignore[return-value]


def fairness_report(
    model: BaseAlgorithm,
    env: gym.Env | VecEnv,
    keys: str | Sequence[str],
    bins: int = 3,
    n_episodes: int = 30,
    out_dir: str | Path | None = None,
    ranges: Mapping[str, Range] | None = None,
    deterministic: bool = True,
    seed: int | None = 0,
) -> dict[str, Any]:
    """Run ``n_episodes`` episodes and report success (or mean return) per bucket of episode attributes.

    Bucket edges are equal-width over ``ranges[key]``, else the env's declared ``attribute_ranges[key]``
    (an env attribute, e.g. ``{"object_scale": (0.5, 1.5)}``), else the observed min/max.

    :param keys: info keys (``"object_scale,object_mass"`` or a sequence).
    :param out_dir: if given, ``fairness.csv`` and ``fairness.png`` are written there.
    :return: see :func:`fairness_from_episodes`.
    """
    venv = as_vec_env(env)
    key_list = split_keys(keys)
    episodes = run_episodes(model, venv, n_episodes, deterministic, seed)
    report = fairness_from_episodes(episodes, key_list, bins, _declared_ranges(venv, key_list, ranges))
    if out_dir is not None:
        out = output_dir(out_dir, None)
        write_fairness_csv(report, out / FAIRNESS_CSV)
        plot_fairness(report, out / FAIRNESS_PNG)
    return report


class FairnessEvalCallback(PeriodicEvalCallback):
    """Run :func:`fairness_report` every ``eval_freq`` calls (vec steps) and at training end.

    Logs ``fairness/worst`` (lowest bucket value), ``fairness/gap`` (max - min) and ``fairness/overall``;
    writes ``fairness.csv`` and ``fairness.png`` (latest evaluation) to ``path`` (else the logger's dir).

    :param eval_env: evaluation env reporting the attributes in ``info``.
    :param keys: attribute keys (``"object_scale,object_mass"`` or a sequence).
    :param bins: buckets per key.
    :param eval_freq: calls between evaluations; <= 0: only at training end.
    :param n_eval_episodes: episodes per evaluation.
    :param ranges: bucket ranges per key (overrides the env's ``attribute_ranges``).
    :param seed: env seed of every evaluation; None: 0.
    """

    def __init__(
        self,
        eval_env: gym.Env | VecEnv,
        keys: str | Sequence[str],
        bins: int = 3,
        eval_freq: int = 10_000,
        n_eval_episodes: int = 30,
        path: str | Path | None = None,
        ranges: Mapping[str, Range] | None = None,
        deterministic: bool = True,
        seed: int | None = None,
        eval_at_end: bool = True,
        verbose: int = 0,
    ) -> None:
        super().__init__(int(eval_freq), eval_at_end, verbose)
        self.eval_env = as_vec_env(eval_env)
        self.keys = split_keys(keys)
        if not self.keys:
            raise ValueError("FairnessEvalCallback needs at least one attribute key")
        self.bins, self.n_eval_episodes = int(bins), int(n_eval_episodes)
        self.path = None if path is None else Path(path)
        self.ranges, self.deterministic = ranges, deterministic
        self.seed = 0 if seed is None else int(seed)
        self.last_report: dict[str, Any] | None = None

    def evaluate(self) -> dict[str, Any]:
        """Evaluate now, log and write the files."""
        sync_normalization(self.training_env, self.eval_env)
        out = output_dir(self.path, self.logger.get_dir())
        report = fairness_report(
            self.model, self.eval_env, self.keys, self.bins, self.n_eval_episodes, out, self.ranges,
            self.deterministic, self.seed,
        )
        report["timesteps"] = self.num_timesteps
        if report["worst"] is not None:
            self.logger.record("fairness/worst", report["worst"]["value"])
            self.logger.record("fairness/gap", report["gap"])
        filled = [b for b in report["buckets"] if b["n"]]
        overall = sum(b["value"] * b["n"] for b in filled) / max(sum(b["n"] for b in filled), 1)
        self.logger.record("fairness/overall", overall)
        if self.verbose >= 1:
            worst = report["worst"]["value"] if report["worst"] else float("nan")
            print(f"fairness: overall {overall:.3g}, worst {worst:.3g}, gap {report['gap']:.3g}")
        self.last_report = report
        self._last_eval_step = self.num_timesteps
        return report

