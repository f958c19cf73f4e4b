"""Load time per model: the rebuild from plain data and weights (no decoder) beside SB3's unpickling loader and beside
the restricted pickle decoder sbagents used before (commit 2487ebf), on the same model files::

    python -m benchmarks run model-load [--repeats 30]

Each model is built on a small env, trained for a few hundred steps (so its optimizer has state) and saved by
sbagents; each loader then loads the same file ``--repeats`` times in this process, on CPU, one torch thread. Rows:
median milliseconds per load and the ratio to SB3's own ``cls.load`` (``--trust-run``'s path) measured in the same
command. The old decoder is read from git (``git show 2487ebf:sbagents/plain_data.py``) when this is a checkout that
has that commit; otherwise its column is empty.

Results: ``benchmarks/results/model_load.json``; section ``model-load`` of ``BENCHMARKS.md``.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import statistics
import subprocess
import tempfile
import time
import types
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.report import recorded_argv

SECTION = "model-load"
OLD_COMMIT = "2487ebf"
#: (algo, env id, policy) of the models loaded.
MODELS: tuple[tuple[str, str], ...] = (
    ("ppo", "CartPole-v1"), ("dqn", "CartPole-v1"), ("sac", "Pendulum-v1"), ("td3", "Pendulum-v1"),
    ("tqc", "Pendulum-v1"), ("ppo", "sbagents/SmartHome-v0"),
)


def _old_decoder() -> types.ModuleType | None:
    """The restricted pickle decoder of :data:`OLD_COMMIT`, from git, or None outside such a checkout."""
    root = Path(__file__).resolve().parents[2]
    try:
        source = subprocess.run(["git", "-C", str(root), "show", f"{OLD_COMMIT}:sbagents/plain_data.py"],
                                capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    import importlib.util

    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as file:
        file.write(source)
    spec = importlib.util.spec_from_file_location("plain_data_2487ebf", file.name)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # this repository's own code, at an earlier commit
    os.unlink(file.name)
    return module


def _old_load(decoder: types.ModuleType) -> Callable[[Any, Path], Any]:
    def load(cls: Any, path: Path) -> Any:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data"))
        objects = {k: decoder.plain_loads(base64.b64decode(v[":serialized:"]), k)
                   for k, v in data.items() if isinstance(v, dict) and ":serialized:" in v}
        return cls.load(str(path), device="cpu", custom_objects=objects)

    return load


def _median_ms(fn: Callable[[], Any], repeats: int) -> float:
    fn()  # warm-up (imports, first allocations)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times)


def run(argv: Sequence[str]) -> dict[str, Any]:
    """``python -m benchmarks run model-load [--repeats N]``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}",
                                     description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--repeats", type=int, default=30, help="loads per model and loader (median reported)")
    parser.add_argument("--n-timesteps", type=int, default=300, help="training steps before saving each model")
    args = parser.parse_args(list(argv))
    import gymnasium as gym
    import torch

    import sbagents  # noqa: F401 - registers the book's env ids
    from sbagents.algos import ALGOS
    from sbagents.atomic import save_model
    from sbagents.safe_load import load_model

    torch.set_num_threads(1)
    decoder = _old_decoder()
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for algo, env_id in MODELS:
            cls: Any = ALGOS[algo].cls
            extra: dict[str, Any] = ({"learning_starts": 100} if ALGOS[algo].off_policy
                                     else {"n_steps": 64, "batch_size": 64})
            model = cls("MlpPolicy", gym.make(env_id), seed=0, **extra)
            model.learn(args.n_timesteps)
            path = save_model(model, Path(folder) / f"{algo}_{env_id.replace('/', '_')}.zip")
            env = gym.make(env_id)
            row: dict[str, Any] = {"algo": algo, "env": env_id, "bytes": path.stat().st_size}
            row["sb3_ms"] = _median_ms(lambda: cls.load(str(path), device="cpu"), args.repeats)  # noqa: B023
            row["rebuild_ms"] = _median_ms(lambda: load_model(cls, path), args.repeats)  # noqa: B023
            row["rebuild_env_ms"] = _median_ms(lambda: load_model(cls, path, env=env), args.repeats)  # noqa: B023
            if decoder is not None:
                old = _old_load(decoder)
                row["decoder_ms"] = _median_ms(lambda: old(cls, path), args.repeats)  # noqa: B023
            rows.append(row)
    return {"command": " ".join(["python -m benchmarks run", SECTION, *recorded_argv(list(argv))]),
            "repeats": args.repeats, "load": round(os.getloadavg()[0], 1), "old_commit": OLD_COMMIT, "rows": rows}


def markdown(results: dict[str, Any]) -> str:
    """The ``model-load`` section, from the results alone."""
    lines = [
        "## Model load time: rebuilt from plain data, beside SB3's loader and the old decoder",
        "",
        f"Command: `{results['command']}` (median of {results['repeats']} loads of the same file per model and "
        f"loader, CPU, one torch thread, machine load ~{results['load']:.1f}). *SB3 `load`* unpickles the zip "
        "(`--trust-run`'s path); *rebuild* is the default (no pickled entry read; without an env the spaces come "
        "from the model's plain record, with one they are checked against it); *decoder* is the restricted "
        f"unpickler sbagents used before ({results['old_commit']}), removed now.",
        "",
        "| model | file | SB3 `load` | rebuild | rebuild with env | decoder (before) | rebuild / SB3 |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for row in results["rows"]:
        decoder = f"{row['decoder_ms']:.1f} ms" if "decoder_ms" in row else "-"
        lines.append(f"| {row['algo']} {row['env']} | {row['bytes'] / 1024:.0f} KiB | {row['sb3_ms']:.1f} ms | "
                     f"{row['rebuild_ms']:.1f} ms | {row['rebuild_env_ms']:.1f} ms | {decoder} | "
                     f"{row['rebuild_ms'] / row['sb3_ms']:.2f}x |")
    if results.get("notes"):
        lines += ["", results["notes"]]
    return "\n".join(lines)


BENCHMARKS = (
    Benchmark(name=SECTION, kind="speed", results="model_load.json",
              summary="load time per model: rebuilt from plain data vs SB3's unpickling load vs the old decoder",
              run=run, render=markdown),
)
