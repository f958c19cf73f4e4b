"""Training-speed overhead of the trust callbacks (PPO, n_envs=8), measured in one process.

Runs PPO (64-64 MLP, 1 torch thread) on GridWorld and SmartHome without callbacks and with each callback,
interleaving the variants and repeating them so machine load affects all alike; prints a Markdown table
of the median fps and the overhead relative to the no-callback baseline. fps is computed from the
process's CPU time (``time.process_time``, single-threaded run) because wall time on a shared machine
varies by +-20% between identical runs; wall-clock fps is shown too.

    python benchmarks/callback_overhead.py [--timesteps 16384] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env

import sbagents  # noqa: F401  (registers the env ids)
from sbagents.callbacks import SafetyViolationCallback, TransparencyCSVCallback
from sbagents.envs.smart_home import SmartHomeEnv

EnvId = Callable[..., object] | str
ENVS: dict[str, EnvId] = {"GridWorld": "sbagents/GridWorld-v0", "SmartHome": SmartHomeEnv}


def _variants(tmp: Path) -> dict[str, Callable[[], list[BaseCallback]]]:
    return {
        "none": lambda: [],
        "transparency .csv": lambda: [TransparencyCSVCallback(tmp / f"{time.time_ns()}.csv")],
        "transparency .csv.gz": lambda: [TransparencyCSVCallback(tmp / f"{time.time_ns()}.csv.gz")],
        "safety": lambda: [SafetyViolationCallback(path=tmp, verbose=0)],
    }


def _fps(env_id: EnvId, callbacks: list[BaseCallback], timesteps: int) -> tuple[float, float]:
    """(CPU-time fps, wall-clock fps) of one PPO run."""
    env = make_vec_env(env_id, n_envs=8, seed=0)  # type: ignore[arg-type]
    model = PPO("MlpPolicy", env, n_steps=128, batch_size=256, seed=0, policy_kwargs={"net_arch": [64, 64]})
    start, cpu = time.perf_counter(), time.process_time()
    model.learn(timesteps, callback=callbacks)
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu
    env.close()
    return model.num_timesteps / cpu_seconds, model.num_timesteps / seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=16_384)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp_dir:
        variants = _variants(Path(tmp_dir))
        results: dict[tuple[str, str], list[tuple[float, float]]] = {}
        for name, env_id in ENVS.items():
            _fps(env_id, [], 2048)  # warm-up
            for _ in range(args.repeats):
                for variant, make in variants.items():
                    results.setdefault((name, variant), []).append(_fps(env_id, make(), args.timesteps))
    print(f"PPO, n_envs=8, {args.timesteps} steps, median of {args.repeats} interleaved runs\n")
    print("| env | callbacks | fps (CPU time) | overhead | fps (wall) |")
    print("|---|---|---:|---:|---:|")
    for name in ENVS:
        base = statistics.median(r[0] for r in results[(name, "none")])
        for variant in variants:
            fps = statistics.median(r[0] for r in results[(name, variant)])
            wall = statistics.median(r[1] for r in results[(name, variant)])
            print(f"| {name} | {variant} | {fps:,.0f} | {100 * (base - fps) / base:+.1f}% | {wall:,.0f} |")


if __name__ == "__main__":
    main()
