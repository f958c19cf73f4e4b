"""The test suite's wall time: the commit before a change and the commit after, side by side, in one command.

Each variant checks its commit out into a temporary git worktree and runs ``python -m pytest -q -p no:cacheprovider``
there (``PYTHONPATH`` pointing at that checkout, the interpreter running this command), one variant after the other on
the same machine. The default variants: the whole suite at ``--before``, the whole suite at ``--after``, and the
developer's loop ``-m "not slow"`` at ``--after``.

    python -m benchmarks run suite-time --before eb0d483 --after HEAD
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.report import BENCHMARKS_DIR, load_average, machine_info

NAME = "suite-time"
REPO = BENCHMARKS_DIR.parent
_COUNTS = re.compile(r"(\d+) (passed|failed|skipped|errors?|deselected|xfailed|xpassed)")


def build_parser() -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run suite-time``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME}", description=__doc__.splitlines()[0])
    parser.add_argument("--before", required=True, help="the commit before (a git revision)")
    parser.add_argument("--after", default="HEAD", help="the commit after (default: HEAD)")
    parser.add_argument("--no-quick-loop", action="store_true", help="skip the -m 'not slow' variant")
    parser.add_argument("--xdist", type=int, default=0, metavar="N",
                        help="also run the whole suite at --after with pytest-xdist's N workers (-n N --dist loadfile)")
    parser.add_argument("--pytest-args", nargs="*", default=[], help="extra pytest arguments for every variant "
                        "(e.g. a test file, for a smoke run)")
    return parser


def _rev(rev: str) -> str:
    out = subprocess.run(["git", "rev-parse", "--short=7", f"{rev}^{{commit}}"], cwd=REPO, capture_output=True,
                         text=True, check=True)
    return out.stdout.strip()


def pytest_counts(output: str) -> dict[str, int]:
    """``{"passed": n, "skipped": n, ...}`` from pytest's last summary line."""
    last = next((line for line in reversed(output.splitlines()) if " in " in line and _COUNTS.search(line)), "")
    return {kind.rstrip("s") if kind.startswith("error") else kind: int(n) for n, kind in _COUNTS.findall(last)}


def time_suite(rev: str, pytest_args: Sequence[str]) -> dict[str, Any]:
    """Run pytest on a fresh worktree of ``rev``: wall seconds, exit code and the summary counts."""
    with tempfile.TemporaryDirectory(prefix="suite-time-") as tmp:
        tree = Path(tmp) / "tree"
        subprocess.run(["git", "worktree", "add", "--detach", "--quiet", str(tree), rev], cwd=REPO, check=True)
        try:
            env = {**os.environ, "PYTHONPATH": str(tree)}
            start = time.perf_counter()
            proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *pytest_args],
                                  cwd=tree, env=env, capture_output=True, text=True)
            wall = time.perf_counter() - start
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=REPO, check=False)
    return {"rev": rev, "pytest_args": list(pytest_args), "wall_s": round(wall, 1), "returncode": proc.returncode,
            "counts": pytest_counts(proc.stdout)}


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Time the variants one after the other; the machine line and load averages beside them."""
    args = build_parser().parse_args(list(argv))
    before, after = _rev(args.before), _rev(args.after)
    variants: list[tuple[str, str, list[str]]] = [(before, "whole suite", []), (after, "whole suite", [])]
    if args.xdist:
        variants.append((after, f"whole suite, {args.xdist} xdist workers", ["-n", str(args.xdist), "--dist",
                                                                             "loadfile"]))
    if not args.no_quick_loop:
        variants.append((after, "developer loop", ["-m", "not slow"]))
    load_before = load_average()
    rows = []
    for rev, label, extra in variants:
        row = time_suite(rev, [*extra, *args.pytest_args])
        rows.append({"label": label, **row, "load_after": load_average()})
        print(f"{label} at {rev}: {row['wall_s']:.0f} s, {row['counts']}", flush=True)
    argv_text = " ".join(["--before", before, "--after", after, *(["--xdist", str(args.xdist)] if args.xdist else []),
                          *(["--no-quick-loop"] if args.no_quick_loop else []),
                          *(["--pytest-args", *args.pytest_args] if args.pytest_args else [])])
    return {"command": f"python -m benchmarks run {NAME} {argv_text}",
            "machine": {**machine_info(), "load_before": load_before}, "runs": rows}


def _counts_text(counts: dict[str, int]) -> str:
    return ", ".join(f"{n} {kind}" for kind, n in counts.items()) or "-"


def render(results: dict[str, Any]) -> str:
    """The section: one row per variant with its wall time and its ratio to the first (the commit before)."""
    m, runs = results["machine"], results["runs"]
    base = runs[0]["wall_s"]
    lines = [
        "## Test suite wall time, before and after",
        "",
        f"Command: `{results['command']}`. {m['cpu']}, {m['cores']} cores, Python {m['python']}, torch {m['torch']}; "
        f"{m['date']}; load average {m['load_before'][0]} at the start. Each variant runs `python -m pytest -q` "
        "on a fresh worktree of its commit, one after the other.",
        "",
        "| commit | variant | pytest arguments | tests | exit | wall s | speed-up vs the first row | load after |",
        "|---|---|---|---|---:|---:|---:|---:|",
    ]
    for r in runs:
        extra = " ".join(r["pytest_args"]) or "-"
        lines.append(f"| {r['rev']} | {r['label']} | `{extra}` | {_counts_text(r['counts'])} | {r['returncode']} | "
                     f"{r['wall_s']:.0f} | {base / r['wall_s']:.2f}x | {r['load_after'][0]} |")
    return "\n".join(lines)


BENCHMARKS = (
    Benchmark(name=NAME, kind="suites", results="suite_time.json",
              summary="the test suite's wall time at two commits side by side (and the `not slow` loop)",
              run=run, render=render),
)
