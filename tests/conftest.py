"""Suite-wide settings: the ``slow`` marker and one torch thread.

``python -m pytest`` (README command 2, ``.ci/run``) runs everything; a developer's quick loop skips the few long
tests with ``python -m pytest -m "not slow"``.
"""

from __future__ import annotations

import pytest
import torch


def pytest_configure(config: pytest.Config) -> None:
    """Register the suite's markers (``--strict-markers`` in ``pyproject.toml`` rejects unknown ones)."""
    config.addinivalue_line("markers", "slow: a long test (> ~10 s here); `-m \"not slow\"` skips it")


@pytest.fixture(autouse=True, scope="session")
def _one_torch_thread() -> None:
    """One torch thread, like the training entry points (small nets: 75 ms vs 0.7 ms per step on 2 cores)."""
    torch.set_num_threads(1)
