"""The learning results recorded in ``benchmarks/results/`` by other benchmarks, as one table (no training).

Reads ``learning_<env>.json`` (benchmarks ``learning-smarthome`` and ``learning-treasure-hunt-ppo``: every
algorithm's runs on one env) and ``treasure_hunt_learning.json`` (benchmark ``treasure-hunt-learning``) and makes one
row per algorithm and file: seeds, the env's key metric per seed with its mean +- std and IQM [95% CI], success,
train seconds, the date the file records and the command that regenerates it. The rows are collected when the
benchmark runs and stored in ``recorded_learning.json``, so rendering reads nothing else::

    python -m benchmarks run recorded-learning [--results-dir benchmarks/results]
"""

from __future__ import annotations

import argparse
import shlex
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.learning.learning import KEY_METRICS, key_metric
from benchmarks.report import RESULTS_DIR, load_results, recorded_argv
from benchmarks.stats import stats_columns

NAME = "recorded-learning"
TREASURE_HUNT_FILE = "treasure_hunt_learning.json"


def _range(values: Sequence[float | None], fmt: str) -> str:
    """``lo-hi`` of the non-missing values formatted with ``fmt`` (one value if they are equal)."""
    vals = [v for v in values if v is not None]
    if not vals:
        return "-"
    lo, hi = format(min(vals), fmt), format(max(vals), fmt)
    return lo if lo == hi else f"{lo}-{hi}"


def _seeds(seeds: Sequence[int]) -> str:
    return " ".join(str(s) for s in sorted(seeds))


def _date(data: dict[str, Any]) -> str:
    """The date a results file records (``date``, else its machine's run date; ``-`` when neither)."""
    return str(data.get("date") or (data.get("machine") or {}).get("date", "-"))[:10]


def _metric(values: Sequence[float], stats: dict[str, Any] | None, fmt: str) -> dict[str, Any]:
    """The key metric's cells (per seed, mean +- std, IQM [95% CI]): from the statistics the file stores, else
    computed from its per-seed values."""
    if stats is None:
        from benchmarks.stats import seed_stats

        stats = seed_stats(values)
    cells = stats_columns(stats, fmt)
    if len(values) < 2:
        cells[1:] = ["-", "-"]
    return dict(zip(("per_seed", "mean_std", "iqm_ci"), cells, strict=True))


def learning_rows(path: Path) -> list[dict[str, Any]]:
    """One row per algorithm of a ``learning_<env>.json`` file (``{env, algos, runs: {algo: [summary]}, ...}``)."""
    data: dict[str, Any] = load_results(path)
    env, rows = data["env"], []
    key, label, fmt = KEY_METRICS.get(env, ("mean_return", "mean return", ".2f"))
    fmt = ".1%" if key.endswith("_share") else fmt
    for algo in data["algos"]:
        runs = data["runs"][algo]
        values = [float(r["eval"]["mean_return"]) if key == "mean_return" else key_metric(env, r) for r in runs]
        rows.append({
            "env": env, "algo": algo, "seeds": _seeds([int(r["seed"]) for r in runs]),
            "n_timesteps": _range([r["n_timesteps"] for r in runs], ",d"), "metric": label,
            **_metric([float(v) for v in values if v is not None], data.get("stats", {}).get(algo, {}).get(key), fmt),
            "success": _range([r["eval"].get("success_rate") for r in runs], ".2f"),
            "train_s": _range([r["train_seconds"] for r in runs], ".1f"),
            "date": _date(data), "file": path.name, "command": data["command"],
        })
    return rows


def treasure_hunt_row(path: Path) -> dict[str, Any]:
    """Summary of ``treasure_hunt_learning.json`` (``{params, runs, target_met, command, ...}``)."""
    data: dict[str, Any] = load_results(path)
    runs = data["runs"]
    via = sorted({str(r.get("via", "?")) for r in runs})
    met = data.get("target_met")
    target = "" if met is None else (", target met" if met else ", target not met")
    return {
        "env": "treasure_hunt_v0", "algo": f"ppo (batched, {'/'.join(via)}{target})",
        "seeds": _seeds([int(r["seed"]) for r in runs]), "n_timesteps": _range([r["n_timesteps"] for r in runs], ",d"),
        "metric": "treasures/episode",
        **_metric([float(r["treasures"]) for r in runs], data.get("stats", {}).get("treasures"), ".2f"),
        "success": _range([r.get("success_rate") for r in runs], ".2f"),
        "train_s": _range([r["train_s"] for r in runs], ".1f"),
        "date": _date(data), "file": path.name, "command": data["command"],
    }


def collect(results_dir: str | Path = RESULTS_DIR) -> list[dict[str, Any]]:
    """One summary row per algorithm and learning results file in ``results_dir`` (sorted by env, file, algo)."""
    folder = Path(results_dir)
    rows = [row for p in sorted(folder.glob("learning_*.json")) for row in learning_rows(p)]
    if (folder / TREASURE_HUNT_FILE).exists():
        rows.append(treasure_hunt_row(folder / TREASURE_HUNT_FILE))
    return sorted(rows, key=lambda r: (r["env"], r["file"], r["algo"]))


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Collect the rows from the results folder; the results (rows and the command)."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME}",
                                     description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--results-dir", default=str(RESULTS_DIR), help="folder of the results files")
    args = parser.parse_args(list(argv))
    command = " ".join([f"python -m benchmarks run {NAME}", *map(shlex.quote, recorded_argv(list(argv)))])
    return {"command": command, "rows": collect(args.results_dir)}


def render(results: dict[str, Any]) -> str:
    """The ``recorded-learning`` section of the collected rows."""
    rows = results["rows"]
    lines = [
        "## Learning results recorded by the learning benchmarks",
        "",
        f"Collected from `benchmarks/results/` by `{results['command']}` (no training). Key metric: per seed, mean "
        "+- std and the IQM with its 95% stratified bootstrap interval (rliable; with 3 seeds the interval is wide); "
        "success and train s are ranges over the seeds. Each row's command regenerates its file (and its own "
        "section above). Dates: the day each file's runs were recorded.",
        "",
        "| env | algo | seeds | timesteps | key metric | per seed | mean +- std | IQM [95% CI] | success | train s "
        "| file (date) | command |",
        "|---|---|---|---:|---|---:|---:|---:|---:|---:|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['env']} | {r['algo']} | {r['seeds']} | {r['n_timesteps']} | {r['metric']} | "
                     f"{r['per_seed']} | {r['mean_std']} | {r['iqm_ci']} | {r['success']} | {r['train_s']} | "
                     f"`{r['file']}` ({r['date']}) | `{r['command']}` |")
    if not rows:
        lines.append("| (no results files) | | | | | | | | | | | |")
    return "\n".join(lines)


BENCHMARKS = (
    Benchmark(name=NAME, kind="learning", results="recorded_learning.json",
              summary="no training: one table over the learning results files (key metric per seed, IQM, command)",
              run=run, render=render),
)
