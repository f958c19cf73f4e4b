"""Running the real CLIs: in this process (:func:`cli`, the default) or in a subprocess (:func:`cli_subprocess`).

A new interpreter costs ~5 s of imports here (torch ~3 s of it), so tests call the CLIs' ``main(argv)`` in-process
through the same :func:`sbagents.cli_common.run` wrapper ``python -m`` uses (exit codes, one-line errors), with
stdout/stderr captured, the working folder, ``sys.argv``, ``os.environ``, the warning filters and torch's thread
count restored afterwards. A subprocess stays where it is the point: signals, import isolation (what a fresh
interpreter imports), the newcomer path, servers, and ``--gym-packages`` (it imports user modules that would stay
registered in this process).
"""

from __future__ import annotations

import contextlib
import importlib
import io
import json
import os
import signal
import subprocess
import sys
import warnings
from pathlib import Path
from typing import Any

import pytest

from sbagents.cli_common import run

REPO = Path(__file__).resolve().parents[1]


def cli(module: str, *args: str, cwd: Path | None = None, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    """Run ``python -m sbagents.<module> args...`` in this process and capture its output.

    :param module: the CLI module under ``sbagents`` (``train``, ``evaluate``, ...).
    :param cwd: the working folder during the call (default: the current one).
    :param timeout: unused in-process (kept so a call can switch to :func:`cli_subprocess` unchanged).
    :return: a ``CompletedProcess`` like :func:`cli_subprocess`'s: ``returncode``, ``stdout``, ``stderr``.
    """
    import torch

    del timeout
    prog = f"python -m sbagents.{module}"
    main = cli_main(module)
    out, err = io.StringIO(), io.StringIO()
    saved_cwd, saved_argv, saved_env = os.getcwd(), sys.argv, dict(os.environ)
    threads = torch.get_num_threads()
    code: int
    try:
        if cwd is not None:
            os.chdir(cwd)
        sys.argv = [prog, *args]
        with warnings.catch_warnings(), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                run(prog, lambda: main(list(args)))
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
                if isinstance(exc.code, str):
                    print(exc.code, file=sys.stderr)
    finally:
        os.chdir(saved_cwd)
        sys.argv = saved_argv
        os.environ.clear()
        os.environ.update(saved_env)
        torch.set_num_threads(threads)
    return subprocess.CompletedProcess([prog, *args], code, out.getvalue(), err.getvalue())


def checked_cli(module: str, *args: str, **_: Any) -> subprocess.CompletedProcess[str]:
    """A stand-in (through ``monkeypatch``) for a benchmark's own ``cli``, which runs ``python -m sbagents.<module>``
    in a subprocess and raises on failure: the module's ``main(argv)`` in this process, stdout captured, a nonzero
    exit fails the test. Unlike :func:`cli` it installs no signal handler and keeps the working folder, so the
    benchmarks that run several commands at once in threads (``--jobs``) can use it."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = cli_main(module)(list(args))
    assert not code, (module, args)
    return subprocess.CompletedProcess([module, *args], 0, out.getvalue(), "")


def cli_subprocess(module: str, *args: str, cwd: Path | None = None,
                   timeout: float = 600) -> subprocess.CompletedProcess[str]:
    """Run ``python -m sbagents.<module> args...`` in a new interpreter and capture its output."""
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


def cli_main(module: str) -> Any:
    """The ``main`` that ``python -m sbagents.<module>`` runs: the module's, or its package's ``__main__``'s."""
    imported = importlib.import_module(f"sbagents.{module}")
    if not hasattr(imported, "main") and hasattr(imported, "__path__"):
        imported = importlib.import_module(f"sbagents.{module}.__main__")
    return imported.main


def run_main(module: str, *args: str) -> int:
    """``python -m sbagents.<module> args`` in this process; returns the exit code."""
    main = cli_main(module)
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



def collect_expert(env: str, dataset: str, episodes: int) -> None:
    """``python -m sbagents.collect`` of ``episodes`` episodes of ``env``'s scripted expert into ``dataset`` (no
    reference scores)."""
    assert run_main("collect", "--env", env, "--policy", "scripted", "--episodes", str(episodes), "--dataset",
                    dataset, "--ref-episodes", "0") == 0
