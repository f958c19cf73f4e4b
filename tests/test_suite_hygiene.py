"""The suite's own rules: skips only for optional third-party packages, markers declared."""

from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).resolve().parent
FIRST_PARTY = ("sbagents", "benchmarks", "envs", "callbacks", "cli_helpers")


def _importorskip_targets(path: Path) -> list[tuple[int, str]]:
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "importorskip"
                and node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            found.append((node.lineno, node.args[0].value))
    return found


def test_importorskip_only_for_third_party_packages() -> None:
    """A broken import of our own code must fail, not skip: ``importorskip`` names optional third-party packages."""
    own = [f"{p.name}:{line} {name}" for p in sorted(TESTS.glob("*.py")) for line, name in _importorskip_targets(p)
           if name.split(".")[0] in FIRST_PARTY]
    assert not own, f"importorskip of first-party modules: {own}"


def test_the_scan_sees_importorskip_calls(tmp_path: Path) -> None:
    sample = tmp_path / "sample.py"
    sample.write_text("import pytest\n"
                      "x = pytest.importorskip('sbagents.multiagent')\ny = pytest.importorskip('mpe2')\n")
    assert _importorskip_targets(sample) == [(2, "sbagents.multiagent"), (3, "mpe2")]
