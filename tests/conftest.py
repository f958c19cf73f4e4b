"""Suite-wide settings: the ``slow`` marker, one torch thread, and pytest-xdist's worker count.

README command 2 (and ``.ci/run``) runs everything on one worker per core: ``python -m pytest -n auto --dist
loadfile`` (each test file stays on one worker, so a file's module-scoped trained runs are trained once). A developer's
quick loop skips the few long tests: ``python -m pytest -n auto --dist loadfile -m "not slow"``. Plain
``python -m pytest FILE`` runs in one process, as always.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch


def pytest_configure(config: pytest.Config) -> None:
    """Register the suite's markers (``--strict-markers`` in ``pyproject.toml`` rejects unknown ones)."""
    config.addinivalue_line("markers", "slow: a long test (> ~10 s here); `-m \"not slow\"` skips it")


@pytest.fixture(autouse=True, scope="session")
def _one_torch_thread() -> None:
    """One torch thread, like the training entry points (small nets: 75 ms vs 0.7 ms per step on 2 cores)."""
    torch.set_num_threads(1)


#: Most xdist workers ``-n auto`` starts: each imports torch and SB3 (~0.5-1 GB resident).
MAX_AUTO_WORKERS = 8


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``-n auto``: one worker per core this process may use, at most :data:`MAX_AUTO_WORKERS`
    (``PYTEST_XDIST_AUTO_NUM_WORKERS`` overrides it, as in pytest-xdist)."""
    override = os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS")
    if override:
        return int(override)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(MAX_AUTO_WORKERS, cores))


@pytest.fixture
def datasets(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A fresh Minari datasets root for the test (``MINARI_DATASETS_PATH``)."""
    root = tmp_path / "datasets"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    return root
