"""The dashboard on two hostile files: a transparency log without a newline, and a big monitor file.

Generates, in a temporary folder (or ``--path``), one run dir with a small transparency log, a ``--mib`` MiB log
that has no newline (``transparency_big.csv``), and a second run dir whose ``0.monitor.csv`` is ``--mib`` MiB of
rows (no ``summary.json``, so the runs table reads the monitor file too). Then, each in a fresh child process
(so the peak resident memory is that process's), through the Flask app's test client:

- **log**: a request for the big log in a thread, and 0.2 s later a request for the small log: how long the small
  log's request takes, how long the big log's, and the process's peak resident memory;
- **monitor**: ``/api/curves`` of the monitor run, repeated until the whole file is read (the dashboard reads a
  bounded amount per request): the first request's time, the number of requests and their total time, the peak
  resident memory and the resident memory before the first request (imports and the app).

    python -m benchmarks run dashboard-hostile [--mib 1024] [--path DIR]

Results: ``benchmarks/results/dashboard_hostile.json``; section ``dashboard-hostile`` of ``BENCHMARKS.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import Benchmark

SECTION = "dashboard-hostile"
RUN = "ddpg/sbagents_SmartHome-v0_1"
MONITOR_RUN = "ppo/sbagents_SmartHome-v0_1"
BLOCK = 1 << 20


def generate(folder: Path, mib: int) -> None:
    """The two run dirs under ``folder`` (see the module docstring)."""
    run_dir = folder / RUN
    run_dir.mkdir(parents=True)
    (run_dir / "command.txt").write_text("python -m sbagents.train --algo ddpg --env sbagents/SmartHome-v0\n")
    rows = "".join(f"0,{i // 10},{i % 10},-1.0,{i % 10 == 9},False,,0.0\n" for i in range(60))
    (run_dir / "transparency.csv").write_text("env,episode,step,reward,terminated,truncated,violation,cost\n" + rows)
    block = b"x" * BLOCK
    with (run_dir / "transparency_big.csv").open("wb") as fh:
        for _ in range(max(mib * (1 << 20) // BLOCK, 1)):
            fh.write(block)
    monitor_dir = folder / MONITOR_RUN
    monitor_dir.mkdir(parents=True)
    rng = np.random.default_rng(0)
    n = min(600_000, (mib << 20) // 25 + 1)  # rows of about 25 bytes, written again and again
    body = "".join(f"{r:.6f},{ln},{t:.3f}\n" for r, ln, t in zip(
        rng.normal(-20, 5, n).tolist(), rng.integers(50, 200, n).tolist(), np.arange(1, n + 1).tolist(),
        strict=True)).encode()
    with (monitor_dir / "0.monitor.csv").open("wb") as fh:
        fh.write(b'#{"t_start": 1000.0, "env_id": "sbagents/SmartHome-v0"}\nr,l,t\n')
        written = 0
        while written < mib << 20:
            fh.write(body)
            written += len(body)


def _rss_mib() -> float:
    """Resident memory of this process now (Linux ``/proc``; 0 elsewhere)."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return 0.0


def _peak_mib() -> float:
    """Peak resident memory of this process: ``VmHWM`` (Linux; ``ru_maxrss`` would include the parent's from
    before ``exec``), else ``ru_maxrss``."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except (OSError, ValueError, IndexError):
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def child(scenario: str, folder: Path) -> dict[str, Any]:
    """One scenario in this (fresh) process."""
    from sbagents.dashboard.app import create_app
    from sbagents.dashboard.folders import ServedFolders

    app = create_app(ServedFolders.from_paths([folder]))
    client = app.test_client()
    if scenario == "log":
        api = f"/api/decisions/0/{RUN}?log="
        assert client.get(api + "transparency.csv").status_code == 200  # warm up: imports, the small log's index
        big: dict[str, Any] = {}

        def get_big() -> None:
            start = time.perf_counter()
            big["status"] = app.test_client().get(api + "transparency_big.csv").status_code
            big["s"] = time.perf_counter() - start

        thread = threading.Thread(target=get_big)
        thread.start()
        time.sleep(0.2)
        start = time.perf_counter()
        small = client.get(api + "transparency.csv&start=10&count=5")
        small_s = time.perf_counter() - start
        thread.join()
        return {"small_s": small_s, "small_status": small.status_code, "big_s": big["s"],
                "big_status": big["status"], "peak_mib": _peak_mib()}
    before = _rss_mib()
    times: list[float] = []
    episodes = 0
    while len(times) < 10_000:
        start = time.perf_counter()
        data = client.get(f"/api/curves/0/{MONITOR_RUN}").get_json()
        times.append(time.perf_counter() - start)
        episodes = int(data["train"].get("episodes", len(data["train"]["returns"])))
        if not any("% read" in note for note in data["notes"]):
            break
    return {"first_s": times[0], "requests": len(times), "total_s": sum(times), "episodes": episodes,
            "points": len(data["train"]["returns"]), "rss_before_mib": before, "peak_mib": _peak_mib()}


#: A scenario's child process (``python -c CHILD SCENARIO FOLDER``): prints its results as one JSON line.
CHILD = ("import json, sys; from pathlib import Path; from benchmarks.suites.dashboard_hostile import child; "
         "print(json.dumps(child(sys.argv[1], Path(sys.argv[2]))))")


def measure(mib: int, path: str | None = None) -> dict[str, Any]:
    """Generate the files, run both scenarios in child processes, return their results."""
    from benchmarks.report import machine_info  # not in the children: their memory is the dashboard's

    folder = Path(path or tempfile.mkdtemp(prefix="sbagents-dashboard-hostile-"))
    try:
        generate(folder / "logs", mib)
        out: dict[str, Any] = {"machine": machine_info(), "mib": mib}
        env = {**os.environ, "SBAGENTS_CACHE_DIR": str(folder / "cache")}
        for scenario in ("log", "monitor"):
            proc = subprocess.run([sys.executable, "-c", CHILD, scenario, str(folder / "logs")],
                                  capture_output=True, text=True, env=env, check=True,
                                  cwd=Path(__file__).resolve().parents[2])
            out[scenario] = json.loads(proc.stdout.strip().splitlines()[-1])
        return out
    finally:
        if path is None:
            shutil.rmtree(folder, ignore_errors=True)


def markdown(result: dict[str, Any]) -> str:
    """The ``dashboard-hostile`` section, from the results alone."""
    log, mon, m = result["log"], result["monitor"], result["machine"]
    return "\n".join([
        "## Dashboard: a log without newline and a big monitor file", "",
        f"Machine: {m.get('cpu', '?')}, {m.get('cores', '?')} cores, Python {m.get('python', '?')}; "
        f"{m.get('date', '')}. Command: `{result['command']}`.", "",
        f"A {result['mib']} MiB transparency log without a newline beside a small log, and a {result['mib']} MiB "
        "monitor file, each scenario served in a fresh process through the app's test client (see "
        "[docs/dashboard.md](docs/dashboard.md) for the limits they test).", "",
        f"| {result['mib']} MiB files | measured |", "|---|---:|",
        f"| request for a small log, 0.2 s after one for the log without newline | {1000 * log['small_s']:.0f} ms |",
        f"| request for the log without newline (answers a note) | {1000 * log['big_s']:.0f} ms |",
        f"| peak memory of that process | {log['peak_mib']:.0f} MiB |",
        f"| monitor file: first `/api/curves` | {1000 * mon['first_s']:.0f} ms |",
        f"| monitor file: requests until read whole, their total | {mon['requests']}, {mon['total_s']:.1f} s |",
        f"| monitor file: episodes, points sent | {mon['episodes']:,}, {mon['points']:,} |",
        f"| monitor file: memory before the first request, peak | {mon['rss_before_mib']:.0f} MiB, "
        f"{mon['peak_mib']:.0f} MiB |",
    ])


def run(argv: Sequence[str]) -> dict[str, Any]:
    """``python -m benchmarks run dashboard-hostile [OPTIONS]``: measure; the results record the command."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mib", type=int, default=1024, help="size of the log without newline and of the monitor file")
    parser.add_argument("--path", default=None, help="folder for the generated files (default: a temporary one)")
    args = parser.parse_args(list(argv))
    result = measure(args.mib, args.path)
    result["command"] = f"python -m benchmarks run {SECTION}" + (f" --mib {args.mib}" if args.mib != 1024 else "")
    return result


BENCHMARKS = (
    Benchmark(name=SECTION, kind="suites", results="dashboard_hostile.json",
              summary="dashboard on hostile files: a 1 GiB log without newline, a 1 GiB monitor file",
              run=run, render=markdown),
)
