"""Serving latency and memory: ``python -m sbagents.serve`` over HTTP vs over stdin/stdout, in one command.

Exports a SmartHome DDPG policy with the shipped network (``zoo_configs/ddpg.yml``: 64-64, VecNormalize of
observations; untrained weights: latency does not depend on them) and starts the torch-free server twice, as a
client on this machine would use it:

- ``stdio``: ``python -m sbagents.serve --model policy.onnx``; one JSON line written, one reply read (the baseline);
- ``http``: ``python -m sbagents.serve --model policy.onnx --http 127.0.0.1:0``; one ``POST /`` per decision over a
  kept-alive ``http.client`` connection.

Each variant gets ``--n`` timed round trips after 50 warm-up ones, with observations drawn from the env's
observation range; p50/p99 are of the client's wall time per round trip. The server's resident memory
(``VmRSS``) and peak (``VmHWM``) are read from ``/proc/<pid>/status`` after the requests.

    python -m benchmarks.serve_latency [--n 2000] [--output BENCHMARKS.md]
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import re
import select
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.speed import machine_info, publish

ENV_ID = "sbagents/SmartHome-v0"
SECTION = "serve-latency"
WARMUP = 50


def export_policy(folder: Path) -> Path:
    """The SmartHome DDPG policy with the shipped network and observation normalization, exported to ONNX."""
    import torch
    from stable_baselines3 import DDPG
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    import sbagents  # noqa: F401 (registers the env ids)
    from sbagents.deploy.exporting import ExportChecks, export_run

    torch.set_num_threads(1)
    venv = VecNormalize(make_vec_env(ENV_ID, n_envs=1, seed=0), norm_reward=False)
    model = DDPG("MlpPolicy", venv, seed=0, device="cpu", buffer_size=1000,
                 policy_kwargs={"net_arch": [64, 64]})
    export_run(model, folder, ENV_ID, vec_normalize=venv, checks=ExportChecks(n_observations=50, latency_n=10))
    return folder / "policy.onnx"


def observations(n: int, seed: int = 0) -> list[str]:
    """``n`` JSON observations drawn uniformly from the env's observation box."""
    import gymnasium as gym

    space = gym.make(ENV_ID).observation_space
    space.seed(seed)
    return [json.dumps([round(float(v), 3) for v in space.sample()]) for _ in range(n)]


def _serve_cmd(model: Path, *args: str) -> list[str]:
    return [sys.executable, "-m", "sbagents.serve", "--model", str(model), *args]


def _memory(pid: int) -> dict[str, float]:
    """Resident and peak resident memory of ``pid`` in MiB."""
    status = Path(f"/proc/{pid}/status").read_text()
    kib = {key: int(re.search(rf"^{key}:\s+(\d+) kB", status, re.M).group(1))  # type: ignore[union-attr]
           for key in ("VmRSS", "VmHWM")}
    return {"rss_mib": round(kib["VmRSS"] / 1024, 1), "peak_rss_mib": round(kib["VmHWM"] / 1024, 1)}


def _summary(seconds: list[float]) -> dict[str, float]:
    us = np.asarray(seconds) * 1e6
    return {"p50_us": round(float(np.percentile(us, 50)), 1), "p99_us": round(float(np.percentile(us, 99)), 1),
            "mean_us": round(float(us.mean()), 1)}


def time_stdio(model: Path, bodies: list[str]) -> dict[str, Any]:
    """Round trips through the line protocol (one line written, one read), then the server's memory."""
    proc = subprocess.Popen(_serve_cmd(model), stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)
    assert proc.stdin is not None and proc.stdout is not None
    seconds = []
    try:
        for i, body in enumerate(bodies):
            start = time.perf_counter()
            proc.stdin.write(body + "\n")
            proc.stdin.flush()
            reply = proc.stdout.readline()
            if i >= WARMUP:
                seconds.append(time.perf_counter() - start)
            if not reply.startswith("["):
                raise RuntimeError(f"stdio serve replied {reply!r}")
        memory = _memory(proc.pid)
    finally:
        proc.stdin.close()
        proc.wait(timeout=30)
    return {**_summary(seconds), **memory}


def time_http(model: Path, bodies: list[str]) -> dict[str, Any]:
    """Round trips of ``POST /`` on one kept-alive connection, then the server's memory."""
    proc = subprocess.Popen(_serve_cmd(model, "--http", "127.0.0.1:0"), stderr=subprocess.PIPE, text=True)
    assert proc.stderr is not None
    try:
        ready, _, _ = select.select([proc.stderr], [], [], 60)
        first = proc.stderr.readline() if ready else ""
        port = re.search(r"http://127\.0\.0\.1:(\d+)/", first)
        if port is None:
            raise RuntimeError(f"the HTTP server did not start: {first!r}")
        conn = http.client.HTTPConnection("127.0.0.1", int(port.group(1)), timeout=30)
        headers = {"Content-Type": "application/json"}
        seconds = []
        for i, body in enumerate(bodies):
            start = time.perf_counter()
            conn.request("POST", "/", body=body, headers=headers)
            reply = conn.getresponse()
            data = reply.read()
            if i >= WARMUP:
                seconds.append(time.perf_counter() - start)
            if reply.status != 200:
                raise RuntimeError(f"HTTP serve replied {reply.status} {data!r}")
        memory = _memory(proc.pid)
        conn.close()
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    return {**_summary(seconds), **memory}


def run(n: int = 2000) -> dict[str, Any]:
    """Export, then time both variants on the same ``n`` observations (+ warm-up)."""
    with tempfile.TemporaryDirectory() as tmp:
        model = export_policy(Path(tmp))
        bodies = observations(n + WARMUP)
        load = os.getloadavg()[0]
        return {"machine": machine_info(), "load": round(load, 2), "n": n, "env_id": ENV_ID,
                "stdio": time_stdio(model, bodies), "http": time_http(model, bodies)}


def markdown(result: dict[str, Any]) -> str:
    """The BENCHMARKS.md section."""
    m = result["machine"]
    base = result["stdio"]
    lines = ["## Serving an exported policy: HTTP vs stdin/stdout", "",
             f"Machine: {m['cpu']}, {m['cores']} cores, Python {m['python']}; {m['date']}, load average "
             f"{result['load']} at the start. SmartHome DDPG (shipped "
             "64-64 network, VecNormalize baked in), `policy.onnx` served by the torch-free "
             "`python -m sbagents.serve`; the client is on the same machine (loopback). "
             f"{result['n']:,} timed round trips per variant after {WARMUP} warm-up ones; memory of the server "
             "process after them. Command: `python -m benchmarks.serve_latency`.", "",
             "| variant | p50 (us) | p99 (us) | mean (us) | p50 / stdio | resident memory (MiB) | peak (MiB) |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for name, label in (("stdio", "stdin/stdout, one line per decision"),
                        ("http", "HTTP, `POST /` on a kept-alive connection")):
        row = result[name]
        lines.append(f"| {label} | {row['p50_us']:,.0f} | {row['p99_us']:,.0f} | {row['mean_us']:,.0f} | "
                     f"{row['p50_us'] / base['p50_us']:.2f}x | {row['rss_mib']:.1f} | {row['peak_rss_mib']:.1f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.serve_latency", description=__doc__)
    parser.add_argument("--n", type=int, default=2000, help="timed round trips per variant")
    parser.add_argument("--output", default="BENCHMARKS.md", help="Markdown file to update ('' = none)")
    parser.add_argument("--json", default="benchmarks/results/serve_latency.json", help="raw results ('' = none)")
    args = parser.parse_args(argv)
    result = run(args.n)
    publish(markdown(result), result, args.output, args.json, SECTION)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
