"""Edge-export latency: SB3 ``model.predict`` vs ONNX fp32 vs int8 (SmartHome DDPG), measured in one process.

Builds DDPG for ``sbagents/SmartHome-v0`` from the shipped zoo config (``zoo_configs/ddpg.yml``: policy,
64-64 net, VecNormalize of observations, action noise), trains it for ``--train-steps`` steps (0: untrained
weights; latency does not depend on the weights, parity barely does), then exports it with
:func:`sbagents.deploy.onnx_export.export_run` (``export_onnx`` + ``quantize_int8`` + ``check_parity`` +
``latency_table``): parity on observations recorded with the greedy policy, single-observation latency
p50/p99 over ``--latency-n`` calls, one torch / onnxruntime thread.

    python -m benchmarks run export-latency [--train-steps 2000] [--latency-n 1000] [--n-observations 1000]
    python -m benchmarks run export-latency --quick    # smoke run: untrained, 200 calls, 200 observations

Results: ``benchmarks/results/export_latency.json``; section ``export-latency`` of ``BENCHMARKS.md``. A ``--quick``
run writes neither: its results go to a scratch file the harness prints (:mod:`benchmarks.__main__`).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.vec_env import VecNormalize

import sbagents  # noqa: F401  (registers the env ids)
from benchmarks.harness import Benchmark
from benchmarks.report import machine_info, recorded_argv
from sbagents.core.env_names import resolve_env
from sbagents.core.experiment import build_experiment
from sbagents.core.options import TrainSpec
from sbagents.deploy.exporting import ExportChecks, export_run
from sbagents.env_factory import make_vec, normalize_for_training
from sbagents.pipeline.models import make_model

ENV_ID = "sbagents/SmartHome-v0"
ALGO = "ddpg"
SECTION = "export-latency"


def run(
    train_steps: int = 2000, latency_n: int = 1000, n_observations: int = 1000, seed: int = 0
) -> dict[str, Any]:
    """Build (and briefly train) the model, export it, measure sizes, parity and latency.

    :param train_steps: ``model.learn`` steps before export (0: export the freshly initialised policy).
    :param latency_n: timed single-observation calls per variant (after 10 warm-up calls).
    :param n_observations: greedy-policy observations ``(n_observations, 5)`` for the parity check.
    :return: JSON-able dict: ``machine``, parameters, ``files`` (bytes), ``parity`` (max abs action
        difference vs SB3), ``latency`` (``{variant: {"p50_us", "p99_us"}}``), ``action_bounds``, ``seconds``.
    """
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    started = time.perf_counter()
    ref = resolve_env(ENV_ID)
    exp = build_experiment(TrainSpec(ALGO, ENV_ID), ref)
    venv = normalize_for_training(make_vec(exp, ref, exp.n_envs, seed), exp)
    model = make_model(exp, venv, seed, "cpu")
    train_start = time.perf_counter()
    if train_steps > 0:
        model.learn(train_steps)
    train_seconds = time.perf_counter() - train_start
    vec_normalize = venv if isinstance(venv, VecNormalize) else None
    record_env = gym.make(ref.env_id, **exp.env_kwargs)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            report = export_run(model, tmp, ref.env_id, env=record_env, vec_normalize=vec_normalize, int8=True,
                                checks=ExportChecks(n_observations, seed, latency_n))
    finally:
        record_env.close()
        venv.close()
    low, high = model.action_space.low, model.action_space.high  # type: ignore[attr-defined]
    machine = machine_info()
    machine["load_before"] = [round(x, 2) for x in load_before]
    machine["load_after"] = [round(x, 2) for x in os.getloadavg()]
    return {
        "machine": machine,
        "env": ENV_ID,
        "algo": ALGO,
        "seed": seed,
        "train_steps": int(model.num_timesteps),
        "train_seconds": round(train_seconds, 2),
        "latency_n": latency_n,
        "n_parity_observations": report.n_parity_observations,
        "files": {"onnx": report.onnx_bytes, "onnx_int8": report.int8_bytes},
        "parity": {"onnx": report.parity_fp32, "onnx_int8": report.parity_int8},
        "latency": report.latency,
        "action_bounds": [[float(a), float(b)] for a, b in zip(np.ravel(low), np.ravel(high), strict=True)],
        "seconds": round(time.perf_counter() - started, 1),
    }


def markdown(results: dict[str, Any]) -> str:
    """The ``export-latency`` Markdown section: sizes, parity and p50/p99 latency per variant."""
    m, lat = results["machine"], results["latency"]
    if results["train_steps"]:
        weights = f"after {results['train_steps']:,} training steps (latency does not depend on the weights)"
    else:
        weights = "with untrained weights (latency does not depend on them)"
    files, parity = results["files"], results["parity"]
    rows = [
        ("SB3 `model.predict` (VecNormalize + torch)", "-", "-", lat["sb3_predict"]),
        ("`policy.onnx` (fp32)", f"{files['onnx']:,} B", f"{parity['onnx']:.1e}", lat["onnx"]),
        ("`policy.int8.onnx` (onnxruntime `quantize_dynamic`)", f"{files['onnx_int8']:,} B",
         f"{parity['onnx_int8']:.2g}", lat["onnx_int8"]),
    ]
    bounds = ", ".join(f"[{lo:g}, {hi:g}]" for lo, hi in results["action_bounds"])
    lines = [
        "## Export latency: SmartHome DDPG, SB3 vs ONNX fp32 vs int8",
        "",
        f"Command: `{results['command']}`. DDPG from the shipped zoo "
        f"config (`zoo_configs/ddpg.yml`, seed {results['seed']}) {weights}; parity = max abs action "
        f"difference vs `model.predict` on {results['n_parity_observations']:,} observations recorded with "
        f"the greedy policy (action bounds {bounds}); single-observation latency over "
        f"{results['latency_n']:,} calls, one thread.",
        "",
        f"Machine: {m['cpu']}, {m['cores']} cores, Python {m['python']}, torch {m['torch']}, "
        f"SB3 {m['stable_baselines3']}; {m['date']}; load average before/after {m['load_before'][0]} / "
        f"{m['load_after'][0]} (shared machine).",
        "",
        "| model | file size | max abs action difference vs SB3 | p50 latency | p99 latency |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, size, parity, row in rows:
        lines.append(f"| {name} | {size} | {parity} | {row['p50_us']:.1f} us | {row['p99_us']:.1f} us |")
    speedup = lat["sb3_predict"]["p50_us"] / lat["onnx"]["p50_us"]
    lines += ["", f"ONNX fp32 p50 is {speedup:.1f}x faster than `model.predict` in this run. p99 depends on "
              "the machine load: on a busy machine the ~80 ms `model.predict` loop is preempted by the "
              "scheduler (ms outliers), the ONNX loops much less."]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run export-latency``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}",
                                     description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--train-steps", type=int, default=2000, help="DDPG steps before export (0: none)")
    parser.add_argument("--latency-n", type=int, default=1000, help="timed calls per variant")
    parser.add_argument("--n-observations", type=int, default=1000, help="observations for the parity check")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true",
                        help="smoke run: no training, 200 calls, 200 observations (overrides those options)")
    return parser


def run_cli(argv: Sequence[str]) -> dict[str, Any]:
    """``python -m benchmarks run export-latency [OPTIONS]``: measure; the results record the command."""
    args = build_parser().parse_args(list(argv))
    if args.quick:
        args.train_steps, args.latency_n, args.n_observations = 0, 200, 200
    results = run(args.train_steps, args.latency_n, args.n_observations, args.seed)
    results["command"] = " ".join(["python -m benchmarks run", SECTION, *recorded_argv(list(argv))])
    return results


BENCHMARKS = (
    Benchmark(name=SECTION, kind="speed", results="export_latency.json",
              summary="SmartHome DDPG: SB3 predict vs ONNX fp32 vs int8 latency, sizes and parity",
              run=run_cli, render=markdown),
)
