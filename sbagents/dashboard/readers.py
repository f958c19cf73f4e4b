"""What the run page shows, read from the files a run dir already has: learning curves (monitor files,
``evaluations.npz``), the run's settings, its files, and the trust callbacks' outputs (``safety.json``,
``adversarial.csv``, ``fairness.csv``).

Every reader tolerates a file that is being written (a partial last line, a half-written ``.npz``) or is malformed:
it returns what it can and adds a one-sentence note.
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from sbagents.dashboard.runs import config_dir, read_json, read_yaml
from sbagents.pipeline.monitor_files import read_monitor_files

#: Files offered for download on the run page, by suffix.
MODEL_SUFFIXES = (".zip", ".pkl", ".onnx", ".json", ".csv", ".gz", ".png", ".npz", ".yml", ".txt")
VIDEO_SUFFIXES = (".mp4", ".webm")
#: Transparency logs the decisions page can open.
LOG_PATTERNS = ("transparency*.csv", "transparency*.csv.gz", "videos/*.csv")


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def read_monitor_episodes(run_dir: Path, notes: list[str]) -> dict[str, list[float]]:
    """Training episodes of every monitor file, ordered by end time: ``timesteps`` (cumulative monitor steps times
    ``timesteps_per_env_step`` from ``args.yml``), ``returns``, ``lengths``, ``time`` (seconds since the run began)."""
    episodes = read_monitor_files(run_dir, notes)
    steps = np.cumsum(episodes.lengths) * _timesteps_per_env_step(run_dir)
    return {
        "timesteps": steps.tolist(),
        "returns": episodes.returns.tolist(),
        "lengths": episodes.lengths.tolist(),
        "time": (episodes.end_times - (episodes.t_start or 0.0)).tolist(),
    }


def _timesteps_per_env_step(run_dir: Path) -> float:
    cfg = config_dir(run_dir)
    args = (read_yaml(cfg / "args.yml", []) if cfg else None) or {}
    try:
        return float(args.get("timesteps_per_env_step", 1.0)) if isinstance(args, dict) else 1.0
    except (TypeError, ValueError):
        return 1.0


def read_evaluations(run_dir: Path, notes: list[str]) -> dict[str, list[Any]]:
    """Periodic evaluations (``evaluations.npz``): per evaluation the ``timesteps``, ``mean``, ``std``, ``min``,
    ``max`` of the episode returns, and ``success`` (share of successful episodes, None without successes)."""
    empty: dict[str, list[Any]] = {k: [] for k in ("timesteps", "mean", "std", "min", "max", "success")}
    path = run_dir / "evaluations.npz"
    if not path.exists():
        return empty
    try:
        with np.load(path) as data:
            timesteps = np.asarray(data["timesteps"], dtype=np.float64)
            results = np.asarray(data["results"], dtype=np.float64).reshape(len(timesteps), -1)
            successes = np.asarray(data["successes"], dtype=np.float64) if "successes" in data.files else None
    except Exception as exc:  # a half-written or foreign npz: np.load raises many kinds
        notes.append(f"evaluations.npz could not be read ({type(exc).__name__}); evaluations are not shown")
        return empty
    if results.size == 0:
        return empty
    out = dict(empty)
    out["timesteps"] = timesteps.tolist()
    out["mean"] = results.mean(axis=1).tolist()
    out["std"] = results.std(axis=1).tolist()
    out["min"] = results.min(axis=1).tolist()
    out["max"] = results.max(axis=1).tolist()
    if successes is not None and successes.size and len(successes) == len(timesteps):
        out["success"] = successes.reshape(len(timesteps), -1).mean(axis=1).tolist()
    else:
        out["success"] = [None] * len(timesteps)
    return out


def read_settings(run_dir: Path, notes: list[str]) -> dict[str, Any]:
    """``summary.json``, ``config.yml``, ``args.yml`` (as data) and ``command.txt`` of a run."""
    cfg = config_dir(run_dir)
    command = run_dir / "command.txt"
    try:
        command_text = command.read_text().strip() if command.exists() else None
    except OSError:
        command_text = None
    return {
        "summary": read_json(run_dir / "summary.json", notes),
        "config": read_yaml(cfg / "config.yml", notes) if cfg else None,
        "args": read_yaml(cfg / "args.yml", notes) if cfg else None,
        "command": command_text,
    }


def list_files(run_dir: Path) -> dict[str, list[dict[str, Any]]]:
    """The run's downloadable files: ``models`` (top level), ``exports`` (``export/``), ``videos`` (with the decisions
    sidecar of each video when it exists), ``checkpoints``; paths relative to the run dir."""
    out: dict[str, list[dict[str, Any]]] = {"models": [], "exports": [], "videos": [], "checkpoints": []}

    def item(path: Path) -> dict[str, Any]:
        return {"path": path.relative_to(run_dir).as_posix(), "size": path.stat().st_size}

    for path in sorted(run_dir.iterdir()):
        if path.is_file() and path.suffix in MODEL_SUFFIXES:
            key = "checkpoints" if path.name.startswith("rl_model_") else "models"
            out[key].append(item(path))
    export = run_dir / "export"
    if export.is_dir():
        out["exports"] = [item(p) for p in sorted(export.rglob("*")) if p.is_file()]
    videos = run_dir / "videos"
    if videos.is_dir():
        for path in sorted(videos.iterdir()):
            if path.suffix in VIDEO_SUFFIXES:
                entry = item(path)
                sidecar = path.with_suffix(".csv")
                entry["decisions"] = sidecar.relative_to(run_dir).as_posix() if sidecar.exists() else None
                out["videos"].append(entry)
    return out


def list_logs(run_dir: Path) -> list[str]:
    """Transparency logs of the run (training logs, then the decisions recorded with each video)."""
    found: list[str] = []
    for pattern in LOG_PATTERNS:
        found += [p.relative_to(run_dir).as_posix() for p in sorted(run_dir.glob(pattern)) if p.is_file()]
    return found


def read_csv_rows(path: Path, notes: list[str]) -> list[dict[str, str]]:
    """Rows of a small CSV written by a callback (a partial last line is dropped)."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        return []
    except OSError as exc:
        notes.append(f"{path.name} could not be read ({exc.strerror})")
        return []
    if text and not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
    try:
        return list(csv.DictReader(io.StringIO(text)))
    except csv.Error as exc:
        notes.append(f"{path.name} is malformed ({exc}); not shown")
        return []


def _float(value: str | None) -> float | None:
    try:
        return _finite(float(value)) if value not in (None, "") else None
    except ValueError:
        return None


def read_adversarial(run_dir: Path, notes: list[str]) -> dict[str, Any]:
    """``adversarial.csv`` as return-vs-eps curves: ``timesteps`` (evaluations made) and, per timestep, per attack:
    ``eps``, ``mean_return``, ``std_return``, ``success_rate``, ``violations``."""
    rows = read_csv_rows(run_dir / "adversarial.csv", notes)
    by_step: dict[str, dict[str, dict[str, list[Any]]]] = {}
    clean: dict[str, dict[str, float | None]] = {}
    for row in rows:
        step, attack = row.get("timesteps", ""), row.get("attack", "")
        values = {k: _float(row.get(k)) for k in ("eps", "mean_return", "std_return", "success_rate", "violations")}
        if values["eps"] is None or values["mean_return"] is None:
            continue
        if attack == "none":
            clean[step] = values
            continue
        curve = by_step.setdefault(step, {}).setdefault(attack, {k: [] for k in values})
        for k, v in values.items():
            curve[k].append(v)
    for step, attacks in by_step.items():  # every attack's curve starts at the clean point (eps 0)
        if step in clean:
            for curve in attacks.values():
                for k, v in clean[step].items():
                    curve[k].insert(0, v)
    steps = sorted(by_step, key=lambda s: _float(s) or 0.0)
    return {"timesteps": steps, "curves": by_step}


def read_fairness(run_dir: Path, notes: list[str]) -> dict[str, Any] | None:
    """``fairness.csv``: the bucket keys, the metric name, and per bucket its ranges, ``n``, value and interval."""
    rows = read_csv_rows(run_dir / "fairness.csv", notes)
    if not rows:
        return None
    columns = list(rows[0])
    keys = [c[: -len("_low")] for c in columns if c.endswith("_low") and c != "ci_low"]
    fixed = {f"{k}_{s}" for k in keys for s in ("low", "high")} | {"n", "successes", "ci_low", "ci_high", "index"}
    metric = next((c for c in columns if c not in fixed), "value")
    buckets = []
    for row in rows:
        buckets.append({
            "ranges": [[_float(row.get(f"{k}_low")), _float(row.get(f"{k}_high"))] for k in keys],
            "n": _float(row.get("n")),
            "value": _float(row.get(metric)),
            "ci": [_float(row.get("ci_low")), _float(row.get("ci_high"))],
        })
    return {"keys": keys, "metric": metric, "buckets": buckets}


def read_safety(run_dir: Path, notes: list[str]) -> list[dict[str, Any]]:
    """Every ``safety*.json`` of the run (one per group for runs of one model per group), with its file name."""
    out = []
    for path in sorted(run_dir.glob("safety*.json")):
        data = read_json(path, notes)
        if isinstance(data, dict):
            out.append({"file": path.name, **data})
    return out


def action_count(run_dir: Path) -> int | None:
    """How many action components the run's model has, read from the JSON ``data`` member of an SB3 model zip
    (the space's ``_shape`` / ``n`` / ``nvec`` fields; nothing is unpickled), or None."""
    import zipfile

    for path in sorted(run_dir.glob("*.zip"), key=lambda p: (p.name.startswith(("best_model", "rl_model_")), p.name)):
        try:
            with zipfile.ZipFile(path) as archive:
                data = json.loads(archive.read("data"))
        except (OSError, KeyError, ValueError, zipfile.BadZipFile):
            continue
        space = data.get("action_space") if isinstance(data, dict) else None
        if not isinstance(space, dict):
            continue
        kind = str(space.get(":type:", ""))
        if "Discrete" in kind and "Multi" not in kind:
            return 1
        shape = space.get("_shape") or space.get("shape")
        if "MultiDiscrete" in kind and isinstance(space.get("nvec"), list):
            return len(space["nvec"])
        if isinstance(shape, list) and all(isinstance(s, int) for s in shape):
            return int(np.prod(shape)) if shape else 1
    return None
