"""Edge export through the CLI: train SmartHome DDPG, export it to ONNX and int8, report sizes, parity and latency.

Runs the two commands a user runs, in a temporary log folder::

    python -m sbagents.train --algo ddpg --env SmartHome-v0 --seed 0
    python -m sbagents.export --algo ddpg --env SmartHome-v0 --int8 --json

and keeps the export's report (file sizes, max abs action difference vs SB3 on greedy-policy observations,
single-observation p50/p99 latency of ``model.predict``, ``policy.onnx`` and ``policy.int8.onnx``)::

    python -m benchmarks run export [--n-timesteps N] [--n-observations 1000]

Results: ``benchmarks/results/edge_export.json``; section ``export`` of ``BENCHMARKS.md``. (``export-latency``
measures the same export in one process on a briefly trained model; this one goes through the CLI with the zoo
config's full training budget.)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.report import recorded_argv

SECTION = "export"
ENV = "SmartHome-v0"


def commands(n_timesteps: int | None, n_observations: int) -> tuple[list[str], list[str]]:
    """The train and export commands (arguments after ``python -m``), without the log folder."""
    train = ["sbagents.train", "--algo", "ddpg", "--env", ENV, "--seed", "0"]
    if n_timesteps is not None:
        train += ["-n", str(n_timesteps)]
    export = ["sbagents.export", "--algo", "ddpg", "--env", ENV, "--int8"]
    if n_observations != 1000:
        export += ["--n-observations", str(n_observations)]
    return train, export


def run(argv: Sequence[str]) -> dict[str, Any]:
    """``python -m benchmarks run export [OPTIONS]``: train, export, return the export's report and the commands."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}",
                                     description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--n-timesteps", type=int, default=None, help="training steps (default: the zoo config's)")
    parser.add_argument("--n-observations", type=int, default=1000, help="observations for the parity check")
    args = parser.parse_args(list(argv))
    train, export = commands(args.n_timesteps, args.n_observations)
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as logs:
        subprocess.run([sys.executable, "-m", *train, "-f", logs, "--verbose", "0"], check=True,
                       stdout=subprocess.DEVNULL)
        out = subprocess.run([sys.executable, "-m", *export, "-f", logs, "--json"], check=True, capture_output=True,
                             text=True).stdout
    report = json.loads(out.strip().splitlines()[-1])
    keep = ("parity_fp32", "parity_int8", "onnx_bytes", "int8_bytes", "int8_deviation", "n_parity_observations",
            "latency")
    return {"command": " ".join(["python -m benchmarks run", SECTION, *recorded_argv(list(argv))]),
            "commands": [" ".join(["python -m", *train]), " ".join(["python -m", *export])],
            "load": round(load, 1), "report": {k: report.get(k) for k in keep}}


def _sci(x: float) -> str:
    """``7.6e-6`` style (one decimal, no exponent padding)."""
    mantissa, exp = f"{x:.1e}".split("e")
    return f"{mantissa}e{int(exp)}"


def markdown(results: dict[str, Any]) -> str:
    """The ``export`` section, from the results alone (``int8_parity_note`` and ``notes``: optional text)."""
    rep, lat = results["report"], results["report"]["latency"]
    train, export = results["commands"]
    note = f" ({results['int8_parity_note']})" if results.get("int8_parity_note") else ""
    n_calls = results.get("latency_n", 1000)
    rows = [
        ("SB3 `model.predict` (VecNormalize + torch)", "-", "-", lat["sb3_predict"]),
        ("`policy.onnx` (fp32)", f"{rep['onnx_bytes']:,} B", _sci(rep["parity_fp32"]), lat["onnx"]),
        ("`policy.int8.onnx` (onnxruntime `quantize_dynamic`)", f"{rep['int8_bytes']:,} B",
         f"{rep['parity_int8']:.2f}{note}", lat["onnx_int8"]),
    ]
    lines = [
        "## Edge export: SmartHome DDPG to ONNX and int8",
        "",
        f"Commands: `{train}`, then",
        f"`{export}` (parity on {rep['n_parity_observations']:,} observations recorded with the",
        f"greedy policy; single-observation latency, {n_calls:,} calls; machine load ~{results['load']:.0f}); "
        f"both run by `{results['command']}`.",
        "",
        "| model | file size | max abs action difference vs SB3 | p50 latency | p99 latency |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, size, parity, row in rows:
        lines.append(f"| {name} | {size} | {parity} | {row['p50_us']:.1f} us | {row['p99_us']:.1f} us |")
    if results.get("notes"):
        lines += ["", results["notes"]]
    return "\n".join(lines)


BENCHMARKS = (
    Benchmark(name=SECTION, kind="suites", results="edge_export.json",
              summary="SmartHome DDPG trained and exported through the CLI: ONNX / int8 sizes, parity, latency",
              run=run, render=markdown),
)
