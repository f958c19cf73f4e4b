"""Running the real CLIs in a subprocess."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]


def cli(module: str, *args: str, cwd: Path | None = None, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    """Run ``python -m sbagents.<module> args...`` and capture its output."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.run(
        [sys.executable, "-m", f"sbagents.{module}", *args],
        capture_output=True, text=True, cwd=cwd, timeout=timeout, env=env,
    )


def popen(module: str, *args: str, cwd: Path | None = None) -> subprocess.Popen[str]:
    """Start ``python -m sbagents.<module> args...`` without waiting."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen(
        [sys.executable, "-m", f"sbagents.{module}", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=cwd, env=env,
    )


def last_json(stdout: str) -> dict[str, Any]:
    """The JSON object on the last stdout line."""
    result: dict[str, Any] = json.loads(stdout.strip().splitlines()[-1])
    return result


def summary(run_dir: Path) -> dict[str, Any]:
    """A run's ``summary.json``."""
    result: dict[str, Any] = json.loads((run_dir / "summary.json").read_text())
    return result
