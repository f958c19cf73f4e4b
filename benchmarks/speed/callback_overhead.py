"""Training-speed overhead of the trust callbacks (PPO, n_envs=8), measured in one process.

Runs PPO (64-64 MLP, 1 torch thread) on GridWorld and SmartHome without callbacks and with each callback,
interleaving the variants and repeating them so machine load affects all alike; reports the median fps
and the overhead relative to the no-callback baseline. fps is computed from the process's CPU time
(``time.process_time``, single-threaded run) because wall time on a shared machine varies by +-20%
between identical runs; wall-clock fps is shown too. Target: at most 10% overhead.

    python -m benchmarks.callback_overhead [--timesteps 16384] [--repeats 5] [--output BENCHMARKS.md]
    python benchmarks/callback_overhead.py ...   (same, as a script)

With ``--output`` the table is written between ``<!-- callback-overhead:start -->`` /
``<!-- callback-overhead:end -->`` of that Markdown file.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

if __package__ in (None, ""):  # run as a script: make the repository root importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch  # noqa: E402
from stable_baselines3 import PPO  # noqa: E402
from stable_baselines3.common.callbacks import BaseCallback  # noqa: E402
from stable_baselines3.common.env_util import make_vec_env  # noqa: E402

import sbagents  # noqa: E402,F401  (registers the env ids)
from benchmarks.report import machine_info, publish  # noqa: E402
from sbagents.callbacks import SafetyViolationCallback, TransparencyCSVCallback  # noqa: E402
from sbagents.envs.smart_home import SmartHomeEnv  # noqa: E402

EnvId = Callable[..., object] | str
ENVS: dict[str, EnvId] = {"GridWorld": "sbagents/GridWorld-v0", "SmartHome": SmartHomeEnv}
VARIANTS: tuple[str, ...] = ("none", "transparency .csv", "transparency .csv.gz", "safety")
N_ENVS = 8
SECTION = "callback-overhead"


def _make_callbacks(variant: str, tmp: Path) -> list[BaseCallback]:
    if variant == "none":
        return []
    if variant == "safety":
        return [SafetyViolationCallback(path=tmp, verbose=0)]
    suffix = variant.split()[-1]  # ".csv" / ".csv.gz"
    return [TransparencyCSVCallback(tmp / f"{time.time_ns()}{suffix}")]


def ppo_fps(env_id: EnvId, callbacks: list[BaseCallback], timesteps: int) -> tuple[float, float]:
    """(CPU-time fps, wall-clock fps) of one PPO run of ``timesteps`` steps on ``N_ENVS`` env copies."""
    env = make_vec_env(env_id, n_envs=N_ENVS, seed=0)  # type: ignore[arg-type]
    model = PPO("MlpPolicy", env, n_steps=128, batch_size=256, seed=0, policy_kwargs={"net_arch": [64, 64]})
    start, cpu = time.perf_counter(), time.process_time()
    model.learn(timesteps, callback=callbacks)
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu
    env.close()
    return model.num_timesteps / cpu_seconds, model.num_timesteps / seconds


def run(
    timesteps: int = 16_384,
    repeats: int = 3,
    envs: Sequence[str] = tuple(ENVS),
    variants: Sequence[str] = VARIANTS,
    warmup: int = 2048,
) -> dict[str, Any]:
    """Measure PPO fps per env and callback variant (variants interleaved, ``repeats`` rounds).

    :param envs: names from :data:`ENVS`.
    :param variants: names from :data:`VARIANTS` (``"none"`` is always measured: it is the baseline).
    :param warmup: steps of one untimed run per env (0: none).
    :return: JSON-able dict: ``machine`` (with ``load_before`` / ``load_after``), parameters, and
        ``results[env][variant] = {"fps_cpu", "fps_wall", "overhead_pct", "samples"}`` (medians;
        ``samples``: ``(fps_cpu, fps_wall)`` per repeat); ``seconds``.
    """
    torch.set_num_threads(1)
    unknown = [v for v in variants if v not in VARIANTS] + [e for e in envs if e not in ENVS]
    if unknown:
        raise ValueError(f"unknown env/variant {unknown}; envs: {list(ENVS)}, variants: {list(VARIANTS)}")
    variants = ["none", *(v for v in variants if v != "none")]
    load_before = os.getloadavg()
    started = time.perf_counter()
    samples: dict[str, dict[str, list[tuple[float, float]]]] = {e: {v: [] for v in variants} for e in envs}
    with tempfile.TemporaryDirectory() as tmp_dir:
        for name in envs:
            if warmup > 0:
                ppo_fps(ENVS[name], [], warmup)
            for _ in range(repeats):
                for variant in variants:
                    cbs = _make_callbacks(variant, Path(tmp_dir))
                    samples[name][variant].append(ppo_fps(ENVS[name], cbs, timesteps))
    results: dict[str, dict[str, dict[str, Any]]] = {}
    for name in envs:
        base = statistics.median(s[0] for s in samples[name]["none"])
        results[name] = {}
        for variant in variants:
            fps = statistics.median(s[0] for s in samples[name][variant])
            results[name][variant] = {
                "fps_cpu": fps,
                "fps_wall": statistics.median(s[1] for s in samples[name][variant]),
                "overhead_pct": 100 * (base - fps) / base,
                "samples": samples[name][variant],
            }
    machine = machine_info()
    machine["load_before"] = [round(x, 2) for x in load_before]
    machine["load_after"] = [round(x, 2) for x in os.getloadavg()]
    return {"machine": machine, "timesteps": timesteps, "repeats": repeats, "n_envs": N_ENVS,
            "results": results, "seconds": round(time.perf_counter() - started, 1)}


def command(results: dict[str, Any]) -> str:
    """The command that reproduces ``results``."""
    cmd = (f"python -m benchmarks.callback_overhead --timesteps {results['timesteps']} "
           f"--repeats {results['repeats']}")
    envs = list(results["results"])
    if envs != list(ENVS):
        cmd += " --envs " + " ".join(envs)
    return cmd


def markdown(results: dict[str, Any]) -> str:
    """The ``callback-overhead`` Markdown section (command, load, table, notes)."""
    m = results["machine"]
    lines = [
        "## Trust callbacks: training-speed overhead",
        "",
        f"Command: `{command(results)}` (also run by `python -m benchmarks`; PPO 64-64, n_envs "
        f"{results['n_envs']} DummyVecEnv, {results['timesteps']:,} steps, median of {results['repeats']} "
        f"interleaved runs in one process; {m['cpu']}, {m['cores']} cores, torch 1 thread; {m['date']}; "
        f"load average before/after {m['load_before'][0]} / {m['load_after'][0]}). Target: at most 10%.",
        "",
        "| env | callbacks | fps (CPU time) | overhead | fps (wall) |",
        "|---|---|---:|---:|---:|",
    ]
    for name, per_variant in results["results"].items():
        for variant, r in per_variant.items():
            lines.append(f"| {name} | {variant} | {r['fps_cpu']:,.0f} | {r['overhead_pct']:+.1f}% | "
                         f"{r['fps_wall']:,.0f} |")
    lines += [
        "",
        "fps (CPU time) is steps per second of process CPU time, which load on a shared machine inflates "
        "less than wall time; overhead is relative to `none` in the same run.",
        "(Before caching the CSV quoting of repeated info strings, GridWorld's transparency log cost "
        "10-17%.)",
    ]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """Arguments of ``python -m benchmarks.callback_overhead``."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.callback_overhead",
                                     description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--timesteps", type=int, default=16_384)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--envs", nargs="+", choices=list(ENVS), default=list(ENVS))
    parser.add_argument("--output", default="", help="Markdown file to update ('' to only print)")
    parser.add_argument("--json", default="", help="raw results file ('' to skip)")
    return parser


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Measure, print the section, and write it into ``--output`` / the raw numbers into ``--json``."""
    args = build_parser().parse_args(argv)
    results = run(args.timesteps, args.repeats, args.envs)
    publish(markdown(results), results, args.output, args.json, SECTION)
    return results


if __name__ == "__main__":
    main()
