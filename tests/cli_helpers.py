"""Running the real CLIs in a subprocess."""

from __future__ import annotations

import importlib
import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from sbagents.cli_common import run

REPO = Path(__file__).resolve().parents[1]


def cli(module: str, *args: str, cwd: Path | None = None, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    """Run ``python -m sbagents.<module> args...`` and capture its output."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.run(
        [sys.executable, "-m", f"sbagents.{module}", *args],
        capture_output=True, text=True, cwd=cwd, timeout=timeout, env=env,
    )


def default_sigint() -> None:
    """In the child: Ctrl-C's default action. A suite started in the background (``cmd &``) inherits an ignored
    SIGINT, and Python then installs no KeyboardInterrupt handler, so the interrupt tests would wait forever."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def popen(module: str, *args: str, cwd: Path | None = None) -> subprocess.Popen[str]:
    """Start ``python -m sbagents.<module> args...`` without waiting (with Ctrl-C's default action)."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen(
        [sys.executable, "-m", f"sbagents.{module}", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=cwd, env=env, preexec_fn=default_sigint,
    )


def last_json(stdout: str) -> dict[str, Any]:
    """The JSON object on the last stdout line."""
    result: dict[str, Any] = json.loads(stdout.strip().splitlines()[-1])
    return result


def summary(run_dir: Path) -> dict[str, Any]:
    """A run's ``summary.json``."""
    result: dict[str, Any] = json.loads((run_dir / "summary.json").read_text())
    return result


def run_main(module: str, *args: str) -> int:
    """``python -m sbagents.<module> args`` in this process; returns the exit code."""
    main = importlib.import_module(f"sbagents.{module}").main
    with pytest.raises(SystemExit) as exit_info:
        run(f"python -m sbagents.{module}", lambda: main(list(args)))
    return int(exit_info.value.code or 0)


def check_error(code: int, stderr: str, expected: str) -> None:
    assert code == 2, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert expected in lines[0], lines[0]
    assert "Traceback" not in stderr


#: Runs ``python -m sbagents.serve`` with torch, SB3 and gymnasium unimportable (the server must not need them).
SERVE_WITHOUT_TORCH = (
    "import runpy, sys\n"
    "for m in ('torch', 'stable_baselines3', 'sb3_contrib', 'gymnasium'):\n"
    "    sys.modules[m] = None\n"
    "sys.argv = ['serve'] + sys.argv[1:]\n"
    "runpy.run_module('sbagents.serve', run_name='__main__')\n"
)


def serve_command(*args: str) -> list[str]:
    """The argv of ``python -m sbagents.serve args...`` without torch (:data:`SERVE_WITHOUT_TORCH`)."""
    return [sys.executable, "-c", SERVE_WITHOUT_TORCH, *args]


#: A BENCHMARKS.md section that writing another section must leave alone.
OTHER_SECTION = "<!-- other:start -->\nkeep me\n<!-- other:end -->\n"


def section_text(text: str, name: str) -> str:
    """The body of the ``<!-- name:start -->`` ... ``<!-- name:end -->`` section of ``text`` (exactly one)."""
    start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    assert text.count(start) == 1 and text.count(end) == 1, f"markers of {name} missing or repeated"
    return text[text.index(start) + len(start) : text.index(end)]

