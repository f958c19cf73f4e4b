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

Then many clients at once: ``--clients`` threads (50) send ``--burst`` requests (1,000) between them to one HTTP
server, each on its own kept-alive connection (a lost one is reopened for the next request), once with every client
released by one barrier ("at once": all connect in the same instant) and once with client ``i`` connecting
``i x 20 ms`` later ("staggered"). Reported: requests lost (no 200 reply: connection reset or refused, dropped
without a reply, timed out) and p50/p99 of the answered ones (a client's first includes its connect).

    python -m benchmarks run serve-latency [--n 2000] [--clients 50] [--burst 1000]
"""

from __future__ import annotations

import argparse
import http.client
import json
import math
import os
import re
import select
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import Benchmark
from benchmarks.report import machine_info, recorded_argv

ENV_ID = "sbagents/SmartHome-v0"
SECTION = "serve-latency"
WARMUP = 50
COMMAND = f"python -m benchmarks run {SECTION}"
#: Start delay between clients in the staggered burst (seconds).
STAGGER = 0.02


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


def _start_http(model: Path) -> tuple[subprocess.Popen[str], int]:
    """``serve --http 127.0.0.1:0`` started; its port from the first line it prints."""
    proc = subprocess.Popen(_serve_cmd(model, "--http", "127.0.0.1:0"), stderr=subprocess.PIPE, text=True)
    assert proc.stderr is not None
    ready, _, _ = select.select([proc.stderr], [], [], 60)
    first = proc.stderr.readline() if ready else ""
    port = re.search(r"http://127\.0\.0\.1:(\d+)/", first)
    if port is None:
        proc.terminate()
        proc.wait(timeout=30)
        raise RuntimeError(f"the HTTP server did not start: {first!r}")
    return proc, int(port.group(1))


def time_http(model: Path, bodies: list[str]) -> dict[str, Any]:
    """Round trips of ``POST /`` on one kept-alive connection, then the server's memory."""
    proc, port = _start_http(model)
    try:
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
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


def _post(conn: http.client.HTTPConnection, body: str) -> tuple[float | None, str]:
    """One ``POST /`` on ``conn`` (which connects first when it is not connected): ``(seconds, "ok")``, or
    ``(None, why it was lost)`` with ``conn`` closed (the next request connects again)."""
    start = time.perf_counter()
    try:
        conn.request("POST", "/", body=body, headers={"Content-Type": "application/json"})
        reply = conn.getresponse()
        reply.read()
        if reply.status != 200:
            return None, f"HTTP {reply.status}"
        return time.perf_counter() - start, "ok"
    except (http.client.HTTPException, OSError) as exc:  # OSError: resets, refusals, timeouts
        conn.close()
        return None, type(exc).__name__


def burst(port: int, bodies: list[str], clients: int, stagger: float) -> dict[str, Any]:
    """``len(bodies)`` requests from ``clients`` threads, each with its own kept-alive connection; client ``i``
    connects ``i * stagger`` s after the barrier that releases them all (0: all at once)."""
    per_client = [bodies[i::clients] for i in range(clients)]
    barrier = threading.Barrier(clients)
    seconds: list[float] = []
    outcomes: Counter[str] = Counter()
    lock = threading.Lock()

    def client(i: int) -> None:
        barrier.wait()
        time.sleep(i * stagger)
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
        for body in per_client[i]:
            took, outcome = _post(conn, body)
            with lock:
                outcomes[outcome] += 1
                if took is not None:
                    seconds.append(took)
        conn.close()

    threads = [threading.Thread(target=client, args=(i,)) for i in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    lost = {k: v for k, v in outcomes.items() if k != "ok"}
    return {"clients": clients, "requests": len(bodies), "stagger_ms": round(stagger * 1000),
            "answered": outcomes["ok"], "lost": sum(lost.values()), "lost_by": lost,
            **(_summary(seconds) if seconds else {})}


def time_bursts(model: Path, bodies: list[str], clients: int) -> dict[str, Any]:
    """The same requests from ``clients`` clients released at once, then staggered, against one server."""
    proc, port = _start_http(model)
    try:
        warm = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
        for body in bodies[:WARMUP]:
            _post(warm, body)
        warm.close()
        return {"at_once": burst(port, bodies, clients, 0.0), "staggered": burst(port, bodies, clients, STAGGER)}
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def run(n: int = 2000, clients: int = 50, burst_requests: int = 1000) -> dict[str, Any]:
    """Export, then time both variants on the same ``n`` observations (+ warm-up), then the bursts of
    ``burst_requests`` from ``clients`` clients (0: none)."""
    with tempfile.TemporaryDirectory() as tmp:
        model = export_policy(Path(tmp))
        bodies = observations(max(n + WARMUP, burst_requests))
        load = os.getloadavg()[0]
        result = {"machine": machine_info(), "load": round(load, 2), "n": n, "env_id": ENV_ID,
                  "stdio": time_stdio(model, bodies[: n + WARMUP]), "http": time_http(model, bodies[: n + WARMUP])}
        if burst_requests:
            result["bursts"] = time_bursts(model, bodies[:burst_requests], clients)
        return result


def markdown(result: dict[str, Any]) -> str:
    """The BENCHMARKS.md section."""
    m = result["machine"]
    base = result["stdio"]
    command = result["command"]
    lines = ["## Serving an exported policy: HTTP vs stdin/stdout", "",
             f"Machine: {m['cpu']}, {m['cores']} cores, Python {m['python']}; {m['date']}, load average "
             f"{result['load']} at the start. SmartHome DDPG (shipped "
             "64-64 network, VecNormalize baked in), `policy.onnx` served by the torch-free "
             "`python -m sbagents.serve`; the client is on the same machine (loopback). "
             f"{result['n']:,} timed round trips per variant after {WARMUP} warm-up ones; memory of the server "
             f"process after them. Command: `{command}`.", "",
             "| variant | p50 (us) | p99 (us) | mean (us) | p50 / stdio | resident memory (MiB) | peak (MiB) |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for name, label in (("stdio", "stdin/stdout, one line per decision"),
                        ("http", "HTTP, `POST /` on a kept-alive connection")):
        row = result[name]
        lines.append(f"| {label} | {row['p50_us']:,.0f} | {row['p99_us']:,.0f} | {row['mean_us']:,.0f} | "
                     f"{row['p50_us'] / base['p50_us']:.2f}x | {row['rss_mib']:.1f} | {row['peak_rss_mib']:.1f} |")
    bursts = result.get("bursts")
    if bursts:
        first = bursts["at_once"]
        lines += ["", f"Many clients: {first['clients']} client threads send {first['requests']:,} `POST /` between "
                  "them to one `--http` server, each client on its own kept-alive connection (reopened after a "
                  "lost request); lost = no 200 reply (reset, refused, dropped, timed out); p50/p99 of the answered "
                  "requests (a client's first includes its connect).", "",
                  "| clients | requests | lost | p50 (ms) | p99 (ms) |", "|---|---:|---:|---:|---:|"]
        for key, label in (("at_once", f"{first['clients']} clients connect at once"),
                           ("staggered", f"{first['clients']} clients, started {bursts['staggered']['stagger_ms']} ms "
                                         "apart")):
            row = bursts[key]
            why = ", ".join(f"{v} {k}" for k, v in sorted(row["lost_by"].items()))
            lines.append(f"| {label} | {row['requests']:,} | {row['lost']}{f' ({why})' if why else ''} | "
                         f"{row.get('p50_us', math.nan) / 1000:,.1f} | {row.get('p99_us', math.nan) / 1000:,.1f} |")
    return "\n".join(lines)


def run_cli(argv: Sequence[str]) -> dict[str, Any]:
    """``python -m benchmarks run serve-latency [OPTIONS]``: measure; the results record the command."""
    parser = argparse.ArgumentParser(prog=COMMAND, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=2000, help="timed round trips per variant")
    parser.add_argument("--clients", type=int, default=50, help="client threads of the bursts")
    parser.add_argument("--burst", type=int, default=1000, help="requests per burst, all clients together (0: none)")
    args = parser.parse_args(list(argv))
    result = run(args.n, args.clients, args.burst)
    result["command"] = " ".join([COMMAND, *recorded_argv(list(argv))])
    return result


BENCHMARKS = (
    Benchmark(name=SECTION, kind="speed", results="serve_latency.json",
              summary="serving an ONNX policy: HTTP vs stdin/stdout latency, memory, bursts of clients",
              run=run_cli, render=markdown),
)
