"""What the run page shows, read from the files a run dir already has: learning curves (monitor files,
``evaluations.npz``), the run's settings, its files, and the trust callbacks' outputs (``safety.json``,
``adversarial.csv``, ``fairness.csv``).

Every file is reached through :class:`~sbagents.dashboard.folders.RunFiles` (its real path stays under the served
folder) and read by the bounded loaders of :mod:`sbagents.dashboard.safeload`. Every reader tolerates a file that is
being written (a partial last line, a half-written ``.npz``) or is malformed: it returns what it can and adds a
one-sentence note.
"""

from __future__ import annotations

import json
import math
import zipfile
from typing import Any

import numpy as np

from sbagents.dashboard.folders import RunFiles
from sbagents.dashboard.monitors import monitor_curve
from sbagents.dashboard.runs import config_dir
from sbagents.dashboard.safeload import SMALL_FILE_BYTES, read_csv_rows, read_mapping, read_npz, read_text

#: Files offered for download on the run page, by suffix (``vecnormalize.pkl`` and ``vecnormalize.npz`` alike).
MODEL_SUFFIXES = (".zip", ".pkl", ".onnx", ".json", ".csv", ".gz", ".png", ".npz", ".yml", ".txt")
VIDEO_SUFFIXES = (".mp4", ".webm")
#: Transparency logs the decisions page can open.
LOG_PATTERNS = ("transparency*.csv", "transparency*.csv.gz", "videos/*.csv")


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def read_monitor_episodes(run: RunFiles, notes: list[str]) -> dict[str, Any]:
    """Training episodes of every monitor file, ordered by end time (see
    :func:`~sbagents.dashboard.monitors.monitor_curve`): ``timesteps`` (cumulative monitor steps times
    ``timesteps_per_env_step`` from ``args.yml``), ``returns``, ``lengths``, ``time`` (seconds since the run began),
    ``episodes`` (all of them; a long run's curve holds every k-th)."""
    return monitor_curve(run, notes, _timesteps_per_env_step(run))


def _timesteps_per_env_step(run: RunFiles) -> float:
    cfg = config_dir(run)
    args = (read_mapping(run, f"{cfg}/args.yml", []) if cfg else None) or {}
    try:
        value = float(args.get("timesteps_per_env_step", 1.0))
    except (TypeError, ValueError, OverflowError):
        return 1.0
    return value if math.isfinite(value) else 1.0


def read_evaluations(run: RunFiles, notes: list[str]) -> dict[str, list[Any]]:
    """Periodic evaluations (``evaluations.npz``): per evaluation the ``timesteps``, ``mean``, ``std``, ``min``,
    ``max`` of the episode returns, and ``success`` (share of successful episodes, None without successes)."""
    empty: dict[str, list[Any]] = {k: [] for k in ("timesteps", "mean", "std", "min", "max", "success")}
    data = read_npz(run, "evaluations.npz", ("timesteps", "results", "successes"), notes)
    if data is None:
        return empty
    try:
        timesteps = np.asarray(data["timesteps"], dtype=np.float64).reshape(-1)
        results = np.asarray(data["results"], dtype=np.float64).reshape(len(timesteps), -1)
        successes = data.get("successes")
        if results.size == 0:
            return empty
        out = dict(empty)
        out["timesteps"] = timesteps.tolist()
        out["mean"] = results.mean(axis=1).tolist()
        out["std"] = results.std(axis=1).tolist()
        out["min"] = results.min(axis=1).tolist()
        out["max"] = results.max(axis=1).tolist()
        if successes is not None and successes.ndim and successes.size and len(successes) == len(timesteps):
            out["success"] = np.asarray(successes, dtype=np.float64).reshape(len(timesteps), -1).mean(axis=1).tolist()
        else:
            out["success"] = [None] * len(timesteps)
    except (KeyError, TypeError, ValueError) as exc:  # arrays missing, of strings, or of shapes that do not fit
        notes.append(f"evaluations.npz could not be read ({type(exc).__name__}); evaluations are not shown")
        return empty
    return out


def read_settings(run: RunFiles, notes: list[str]) -> dict[str, Any]:
    """``summary.json``, ``config.yml``, ``args.yml`` (as data) and ``command.txt`` of a run."""
    cfg = config_dir(run)
    command = read_text(run, "command.txt", notes)
    return {
        "summary": read_mapping(run, "summary.json", notes),
        "config": read_mapping(run, f"{cfg}/config.yml", notes) if cfg else None,
        "args": read_mapping(run, f"{cfg}/args.yml", notes) if cfg else None,
        "command": command.strip() if command is not None else None,
    }


def list_files(run: RunFiles) -> dict[str, list[dict[str, Any]]]:
    """The run's downloadable files: ``models`` (top level), ``exports`` (``export/``), ``videos`` (with the decisions
    sidecar of each video when it exists), ``checkpoints``; paths relative to the run dir."""
    out: dict[str, list[dict[str, Any] | None]] = {"models": [], "exports": [], "videos": [], "checkpoints": []}

    def item(name: str) -> dict[str, Any] | None:
        st = run.stat(name)
        return {"path": name, "size": st.st_size} if st is not None else None

    for name in run.glob("*"):
        if name.endswith(MODEL_SUFFIXES):
            out["checkpoints" if name.startswith("rl_model_") else "models"].append(item(name))
    out["exports"] = [item(name) for name in run.glob("export/**/*")]
    for name in run.glob("videos/*"):
        entry = item(name) if name.endswith(VIDEO_SUFFIXES) else None
        if entry is not None:
            sidecar = name.rsplit(".", 1)[0] + ".csv"
            entry["decisions"] = sidecar if run.file(sidecar) is not None else None
            out["videos"].append(entry)
    return {k: [e for e in v if e is not None] for k, v in out.items()}


def list_logs(run: RunFiles) -> list[str]:
    """Transparency logs of the run (training logs, then the decisions recorded with each video)."""
    return [name for pattern in LOG_PATTERNS for name in run.glob(pattern)]


def video_of(run: RunFiles, log: str) -> str | None:
    """The video a ``videos/*.csv`` decisions log was recorded with (None for other logs or without a video)."""
    if not log.startswith("videos/"):
        return None
    stem = log.rsplit(".", 1)[0]
    found = [stem + suffix for suffix in VIDEO_SUFFIXES if run.file(stem + suffix) is not None]
    return found[-1] if found else None


def _float(value: str | None) -> float | None:
    try:
        return _finite(float(value)) if value not in (None, "") else None
    except (TypeError, ValueError):
        return None


def read_adversarial(run: RunFiles, notes: list[str]) -> dict[str, Any]:
    """``adversarial.csv`` as return-vs-eps curves: ``timesteps`` (evaluations made) and, per timestep, per attack:
    ``eps``, ``mean_return``, ``std_return``, ``success_rate``, ``violations``."""
    rows = read_csv_rows(run, "adversarial.csv", notes)
    by_step: dict[str, dict[str, dict[str, list[Any]]]] = {}
    clean: dict[str, dict[str, float | None]] = {}
    for row in rows:
        step, attack = str(row.get("timesteps") or ""), str(row.get("attack") or "")
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


def read_fairness(run: RunFiles, notes: list[str]) -> dict[str, Any] | None:
    """``fairness.csv``: the bucket keys, the metric name, and per bucket its ranges, ``n``, value and interval."""
    rows = read_csv_rows(run, "fairness.csv", notes)
    if not rows:
        return None
    columns = [c for c in rows[0] if isinstance(c, str)]
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


def read_safety(run: RunFiles, notes: list[str]) -> list[dict[str, Any]]:
    """Every ``safety*.json`` of the run (one per group for runs of one model per group), with its file name."""
    out = []
    for name in run.glob("safety*.json"):
        data = read_mapping(run, name, notes)
        if data is not None:
            out.append({**data, "file": name})
    return out


def action_count(run: RunFiles) -> int | None:
    """How many action components the run's model has, read from the JSON ``data`` member of an SB3 model zip
    (the space's ``_shape`` / ``n`` / ``nvec`` fields; nothing is unpickled), or None."""
    for name in sorted(run.glob("*.zip"), key=lambda n: (n.startswith(("best_model", "rl_model_")), n)):
        fh = run.open(name)
        if fh is None:
            continue
        try:
            with fh, zipfile.ZipFile(fh) as archive:
                info = archive.getinfo("data")
                if info.file_size > SMALL_FILE_BYTES:
                    continue
                data = json.loads(archive.read(info))
        except Exception:  # not a model zip: zipfile and json raise many kinds
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
        if isinstance(shape, list) and all(isinstance(s, int) and 0 <= s < 1 << 31 for s in shape):
            return int(np.prod(shape)) if shape else 1
    return None
