"""The repository passes its own static checks: ``ruff check .`` and ``mypy`` (the config in ``pyproject.toml``), run
from the repository root with the interpreter that runs the tests. A tool that is not installed skips its test."""

from __future__ import annotations

import importlib.util
import subprocess
import sys

import pytest
from cli_helpers import REPO


def _run_tool(module: str, *args: str) -> subprocess.CompletedProcess[str]:
    """``python -m module *args`` in the repository root (skips when ``module`` is not installed)."""
    if importlib.util.find_spec(module) is None:
        pytest.skip(f"{module} is not installed (pip install -e '.[test]')")
    return subprocess.run([sys.executable, "-m", module, *args], cwd=REPO, capture_output=True, text=True,
                          timeout=600)


def test_ruff_check_passes() -> None:
    result = _run_tool("ruff", "check", ".")
    assert result.returncode == 0, f"ruff check . failed:\n{result.stdout}{result.stderr}"


def test_mypy_passes() -> None:
    """mypy resolves every first-party module (no global ignore_missing_imports) and finds no error."""
    result = _run_tool("mypy")
    assert result.returncode == 0, f"mypy failed:\n{result.stdout}{result.stderr}"
    assert "Success: no issues found" in result.stdout


def test_mypy_ignores_named_third_party_modules_only() -> None:
    """No global ``ignore_missing_imports`` and no override for a first-party module: every ``sbagents`` import is
    resolved and typed, none is silently ``Any``."""
    tomllib = pytest.importorskip("tomllib", reason="tomllib is in the standard library from Python 3.11")
    config = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["mypy"]
    assert "ignore_missing_imports" not in config and "follow_imports" not in config
    overrides = config.get("overrides", [])
    assert overrides, "the third-party packages without types are named in [[tool.mypy.overrides]]"
    for override in overrides:
        modules = [override["module"]] if isinstance(override["module"], str) else override["module"]
        first_party = [m for m in modules
                       if m.split(".")[0] in ("sbagents", "benchmarks", "envs", "callbacks", "zoo_configs")]
        assert not first_party, f"a mypy override names first-party modules: {first_party}"
