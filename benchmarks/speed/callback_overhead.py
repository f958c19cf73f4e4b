"""Training-speed overhead of the trust callbacks (PPO, n_envs=8), measured in one process.

Runs PPO (64-64 MLP, 1 torch thread) on GridWorld and SmartHome without callbacks and with each callback,
interleaving the variants and repeating them so machine load affects all alike; reports the median fps
and the overhead relative to the no-callback baseline. fps is computed from the process's CPU time
(``time.process_time``, single-threaded run) because wall time on a shared machine varies by +-20%
between identical runs; wall-clock fps is shown too. Target: at most 10% overhead.

    python -m benchmarks run callback-overhead [--timesteps 16384] [--repeats 5] [--envs GridWorld SmartHome]
    python -m benchmarks run callback-overhead --quick    # smoke run: 4,096 steps, 1 repeat

Results: ``benchmarks/results/callback_overhead.json``; section ``callback-overhead`` of ``BENCHMARKS.md``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env

import sbagents  # noqa: F401  (registers the env ids)
from benchmarks.harness import Benchmark
from benchmarks.report import machine_info, recorded_argv
from sbagents.callbacks import SafetyViolationCallback, TransparencyCSVCallback
from sbagents.envs.smart_home import SmartHomeEnv

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


def markdown(results: dict[str, Any]) -> str:
    """The ``callback-overhead`` Markdown section (command, load, table, notes)."""
    m = results["machine"]
    lines = [
        "## Trust callbacks: training-speed overhead",
        "",
        f"Command: `{results['command']}` (PPO 64-64, n_envs "
        f"{results['n_envs']} DummyVecEnv, {results['timesteps']:,} steps, median of {results['repeats']} "
        f"interleaved runs in one process; {m['cpu']}, {m['cores']} cores, torch 1 thread; {m['date']}; "
        f"load average before/after {m['load_before'][0]} / {m['load_after'][0]}). Target: at most 10%.",
        "",
        "| env | callbacks | fps (CPU time, median) | min-max over runs | overhead | fps (wall) |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for name, per_variant in results["results"].items():
        for variant, r in per_variant.items():
            cpu = [s[0] for s in r["samples"]]
            lines.append(f"| {name} | {variant} | {r['fps_cpu']:,.0f} | {min(cpu):,.0f}-{max(cpu):,.0f} | "
                         f"{r['overhead_pct']:+.1f}% | {r['fps_wall']:,.0f} |")
    lines += [
        "",
        "fps (CPU time) is steps per second of process CPU time, which load on a shared machine inflates "
        "less than wall time; overhead is relative to `none` in the same run.",
        "(Before caching the CSV quoting of repeated info strings, GridWorld's transparency log cost "
        "10-17%.)",
    ]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run callback-overhead``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}",
                                     description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--timesteps", type=int, default=16_384)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--envs", nargs="+", choices=list(ENVS), default=list(ENVS))
    parser.add_argument("--quick", action="store_true", help="smoke run: 4,096 steps, 1 repeat (overrides both)")
    return parser


def run_cli(argv: Sequence[str]) -> dict[str, Any]:
    """``python -m benchmarks run callback-overhead [OPTIONS]``: measure; the results record the command."""
    args = build_parser().parse_args(list(argv))
    timesteps, repeats = (4096, 1) if args.quick else (args.timesteps, args.repeats)
    results = run(timesteps, repeats, args.envs)
    results["command"] = " ".join(["python -m benchmarks run", SECTION, *recorded_argv(list(argv))])
    return results


BENCHMARKS = (
    Benchmark(name=SECTION, kind="speed", results="callback_overhead.json",
              summary="PPO fps with and without the trust callbacks (transparency log, safety)",
              run=run_cli, render=markdown),
)
