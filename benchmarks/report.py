"""What every benchmark shares: results files, BENCHMARKS.md sections, the machine line and number formats.

A benchmark measures into a JSON-able ``results`` object, saves it with :func:`save_results` (written to a
temporary name and renamed into place) and renders its Markdown section from that object alone, so
``python -m benchmarks render NAME`` can rebuild the section without measuring again. Sections live between
``<!-- NAME:start -->`` and ``<!-- NAME:end -->`` in ``BENCHMARKS.md``; :func:`replace_section` replaces one
and leaves the rest of the file as it is.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

#: The repository's benchmark folder, its results folder and the Markdown file the sections live in.
BENCHMARKS_DIR = Path(__file__).resolve().parent
RESULTS_DIR = BENCHMARKS_DIR / "results"
MARKDOWN = BENCHMARKS_DIR.parent / "BENCHMARKS.md"


def markers(name: str) -> tuple[str, str]:
    """The start and end markers of section ``name``."""
    return f"<!-- {name}:start -->", f"<!-- {name}:end -->"


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file in the same folder, renamed into place."""
    atomic_write_bytes(path, text.encode())


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` (its folder created) through a temporary file in the same folder, renamed into
    place."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def read_section(path: str | os.PathLike[str], name: str) -> str | None:
    """The text between section ``name``'s markers in ``path`` (without the markers' newlines); ``None`` when
    the file or the section is missing."""
    try:
        text = Path(path).read_text()
    except OSError:
        return None
    start, end = markers(name)
    if start not in text or end not in text:
        return None
    return text[text.index(start) + len(start) + 1 : text.index(end) - 1]


def section_names(text: str) -> list[str]:
    """The names of the sections in a Markdown text, in order."""
    names = []
    for line in text.splitlines():
        if line.startswith("<!-- ") and line.endswith(":start -->"):
            names.append(line[len("<!-- ") : -len(":start -->")])
    return names


def replace_section(old: str, text: str, name: str) -> str:
    """``old`` with section ``name``'s body replaced by ``text`` (appended at the end when missing)."""
    start, end = markers(name)
    block = f"{start}\n{text}\n{end}"
    if start in old and end in old and old.index(start) < old.index(end):
        return old[: old.index(start)] + block + old[old.index(end) + len(end) :]
    return old.rstrip("\n") + "\n\n" + block + "\n"



def save_results(results: Any, path: str | os.PathLike[str]) -> None:
    """Write ``results`` as indented JSON (one trailing newline), atomically."""
    atomic_write_text(path, json.dumps(results, indent=2) + "\n")


def load_results(path: str | os.PathLike[str]) -> Any:
    """Read a JSON results file."""
    return json.loads(Path(path).read_text())


def kept_rows(path: str | os.PathLike[str], trained: set[tuple[Any, ...]],
              key: Callable[[dict[str, Any]], tuple[Any, ...]],
              skip: Callable[[dict[str, Any]], bool] = lambda row: False) -> tuple[list[dict[str, Any]], list[str]]:
    """The rows of a published results file (``rows``, ``command``, ``earlier_commands``) whose ``key`` is not in
    ``trained`` (and not ``skip``-ped), and the commands that measured them (oldest first; none when no row is kept):
    what a benchmark that measures a few runs per session keeps of the earlier sessions'."""
    if not Path(path).exists():
        return [], []
    published = json.loads(Path(path).read_text())
    rows = [r for r in published["rows"] if not skip(r) and key(r) not in trained]
    return rows, [*published.get("earlier_commands", []), published["command"]] if rows else []


def recorded_argv(argv: list[str]) -> list[str]:
    """``argv`` as a section's command records it: without ``--json``/``--output`` and their values (paths of the
    machine it ran on)."""
    return [a for i, a in enumerate(argv) if not {a, argv[i - 1] if i else ""} & {"--json", "--output"}]


def cpu_model() -> str:
    """The CPU's model name (Linux ``/proc/cpuinfo``), else the platform's processor or machine string."""
    fallback = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            return next((line.split(":", 1)[1].strip() for line in fh if line.startswith("model name")), fallback)
    except OSError:
        return fallback


def machine_info() -> dict[str, Any]:
    """CPU model, core count, library versions and the date of the run."""
    import numpy as np
    import stable_baselines3
    import torch

    return {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "torch": torch.__version__,
        "stable_baselines3": stable_baselines3.__version__,
        "date": time.strftime("%Y-%m-%d %H:%M"),
    }


def load_average() -> list[float]:
    """The 1/5/15-minute load averages (zeros where the platform has none)."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return [0.0, 0.0, 0.0]


def save_figure(fig: Any, path: str | os.PathLike[str], dpi: float | None = None) -> None:
    """Save a matplotlib figure to ``path`` through a temporary file renamed into place, then close it."""
    import matplotlib.pyplot as plt

    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f".{target.stem}.tmp{target.suffix}")
    try:
        fig.savefig(tmp, dpi=dpi)
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)
        plt.close(fig)


def run_module(*args: str, env: dict[str, str]) -> str:
    """``python -m <args>`` in this interpreter with ``env``; its standard output.

    :raises RuntimeError: it failed (the message ends with its standard error's last 600 characters).
    """
    done = subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, env=env, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(args[:3])} failed: {done.stderr.strip()[-600:]}")
    return done.stdout
