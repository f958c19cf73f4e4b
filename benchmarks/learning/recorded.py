"""The learning results recorded in ``benchmarks/results/`` by other benchmarks, as one table (no training).

Reads ``learning_<env>_<algo>.json`` (written by ``python -m benchmarks.learning``: a list of run summaries)
and ``treasure_hunt_learning.json`` (written by ``python -m benchmarks.treasure_hunt_learning``) and makes
one row per file: seeds, the env's key metric (range over seeds), success, train seconds, the date of the
file's last change and the command that regenerates it.

    python -m benchmarks.recorded [--results benchmarks/results] [--output BENCHMARKS.md]
"""

from __future__ import annotations

import argparse
import datetime
import json
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

if __package__ in (None, ""):  # run as a script: make the repository root importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import publish  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
SECTION = "recorded-learning"
TREASURE_HUNT_FILE = "treasure_hunt_learning.json"
# Key metric per env (``eval.metrics`` key, label); envs not listed show the mean return.
#: A metric's earlier name in recorded files.
LEGACY_KEYS: dict[str, str] = {"treasures_collected": "treasures_per_episode"}
KEY_METRICS: dict[str, tuple[str, str]] = {
    "treasure_hunt_v0": ("treasures_collected", "treasures/episode"),
    "sbagents/SmartHome-v0": ("criterion_share", "comfort criterion share"),
}


def _git(path: Path, *args: str) -> str:
    """Stripped stdout of ``git ARGS`` run in ``path``'s folder (read-only commands only)."""
    out = subprocess.run(["git", *args], cwd=path.parent, capture_output=True, text=True, timeout=10,
                         check=True)
    return out.stdout.strip()


def file_date(path: Path) -> str:
    """``YYYY-MM-DD`` of the last commit touching ``path``; the file's mtime (marked ``uncommitted``) when
    it is modified or untracked; ``-`` when neither is known."""
    try:
        status = _git(path, "--no-optional-locks", "status", "--porcelain", "--", path.name)
        if not status:
            date = _git(path, "log", "-1", "--format=%cs", "--", path.name)
            if date:
                return date
    except (OSError, subprocess.SubprocessError):
        pass
    try:
        mtime = datetime.date.fromtimestamp(path.stat().st_mtime).isoformat()
    except OSError:
        return "-"
    return f"{mtime} (uncommitted)"


def _range(values: Sequence[float | None], fmt: str) -> str:
    """``lo-hi`` of the non-missing values formatted with ``fmt`` (one value if they are equal)."""
    vals = [v for v in values if v is not None]
    if not vals:
        return "-"
    lo, hi = format(min(vals), fmt), format(max(vals), fmt)
    return lo if lo == hi else f"{lo}-{hi}"


def _seeds(seeds: Sequence[int]) -> str:
    return " ".join(str(s) for s in sorted(seeds))


def learning_row(path: Path) -> dict[str, Any]:
    """Summary of one ``learning_<env>_<algo>.json`` file (a list of run summaries with ``eval``)."""
    runs: list[dict[str, Any]] = json.loads(path.read_text())
    if not runs:
        raise ValueError(f"{path} holds no runs")
    env, algo = runs[0]["env"], runs[0]["algo"]
    key, label = KEY_METRICS.get(env, ("mean_return", "mean return"))

    def metric(r: dict[str, Any]) -> float | None:
        ev = r["eval"]
        if key == "mean_return":
            return float(ev["mean_return"])
        metrics = ev.get("metrics", {})
        value = metrics.get(key, metrics.get(LEGACY_KEYS.get(key, key)))  # files recorded before a key's rename
        return None if value is None else float(value)

    fmt = ".1%" if key.endswith("_share") else ".2f"
    seeds = [int(r["seed"]) for r in runs]
    return {
        "env": env, "algo": algo, "seeds": _seeds(seeds),
        "n_timesteps": _range([r["n_timesteps"] for r in runs], ",d"),
        "metric": label, "metric_range": _range([metric(r) for r in runs], fmt),
        "success": _range([r["eval"].get("success_rate") for r in runs], ".2f"),
        "train_s": _range([r["train_seconds"] for r in runs], ".1f"),
        "date": file_date(path), "file": path.name,
        "command": f"python -m benchmarks.learning --algo {algo} --env {env} --seeds {_seeds(seeds)}",
    }


def treasure_hunt_row(path: Path) -> dict[str, Any]:
    """Summary of ``treasure_hunt_learning.json`` (``{params, runs, min_treasures, max_train_s,
    target_met}``)."""
    data: dict[str, Any] = json.loads(path.read_text())
    runs = data["runs"]
    seeds = [int(r["seed"]) for r in runs]
    command = f"python -m benchmarks.treasure_hunt_learning --seeds {_seeds(seeds)}"
    if data.get("params"):
        command += f" --params '{json.dumps(data['params'])}'"
    via = sorted({str(r.get("via", "?")) for r in runs})
    met = data.get("target_met")
    target = "" if met is None else (", target met" if met else ", target not met")
    return {
        "env": "treasure_hunt_v0", "algo": f"ppo (batched, {'/'.join(via)}{target})", "seeds": _seeds(seeds),
        "n_timesteps": _range([r["n_timesteps"] for r in runs], ",d"),
        "metric": "treasures/episode", "metric_range": _range([r["treasures"] for r in runs], ".2f"),
        "success": _range([r.get("success_rate") for r in runs], ".2f"),
        "train_s": _range([r["train_s"] for r in runs], ".1f"),
        "date": file_date(path), "file": path.name, "command": command,
    }


def collect(results_dir: str | Path = RESULTS) -> list[dict[str, Any]]:
    """One summary row per learning results file in ``results_dir`` (sorted by env, then file name)."""
    folder = Path(results_dir)
    rows = [learning_row(p) for p in sorted(folder.glob("learning_*.json"))]
    if (folder / TREASURE_HUNT_FILE).exists():
        rows.append(treasure_hunt_row(folder / TREASURE_HUNT_FILE))
    return sorted(rows, key=lambda r: (r["env"], r["file"]))


def markdown(rows: list[dict[str, Any]]) -> str:
    """The ``recorded-learning`` Markdown section of the rows from :func:`collect`."""
    lines = [
        "## Learning results recorded by the learning benchmarks",
        "",
        "Read from `benchmarks/results/` by `python -m benchmarks.recorded` (also run by "
        "`python -m benchmarks`; no training). Ranges are over the seeds; each row's command regenerates "
        "its file (and its own section above). Dates: last commit of the file (file time if uncommitted).",
        "",
        "| env | algo | seeds | timesteps | key metric | range | success | train s | file (date) | command |",
        "|---|---|---|---:|---|---:|---:|---:|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['env']} | {r['algo']} | {r['seeds']} | {r['n_timesteps']} | {r['metric']} | "
                     f"{r['metric_range']} | {r['success']} | {r['train_s']} | `{r['file']}` ({r['date']}) | "
                     f"`{r['command']}` |")
    if not rows:
        lines.append("| (no results files) | | | | | | | | | |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> list[dict[str, Any]]:
    """Print the section and write it into ``--output`` when given."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.recorded",
                                     description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--results", default=str(RESULTS), help="folder of the results files")
    parser.add_argument("--output", default="", help="Markdown file to update ('' to only print)")
    args = parser.parse_args(argv)
    rows = collect(args.results)
    publish(markdown(rows), rows, args.output, None, SECTION)
    return rows


if __name__ == "__main__":
    main()
