"""The package's module-level imports form no cycle (one would fail at import time), and an SB3 run never loads the
RLlib backend. The layers and the package-level graph, imports inside functions included, are checked by
tests/test_layers.py."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

from cli_helpers import REPO

#: Source folder -> the package name it is installed as.
PACKAGES = {"sbagents": "sbagents", "envs": "sbagents.envs", "callbacks": "sbagents.callbacks"}


def project_modules() -> dict[str, Path]:
    """Every module of the package by dotted name."""
    modules: dict[str, Path] = {}
    for folder, package in PACKAGES.items():
        for path in (REPO / folder).rglob("*.py"):
            parts = list(path.relative_to(REPO / folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            modules[".".join([package, *parts])] = path
    return modules


def _module_level(body: list[ast.stmt]) -> list[ast.stmt]:
    """Statements run at import time: not function bodies, not ``if TYPE_CHECKING:`` blocks."""
    out: list[ast.stmt] = []
    for node in body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            out.extend(_module_level(node.orelse))
            continue
        out.append(node)
        inner = [getattr(node, field, None) for field in ("body", "orelse", "finalbody")]
        inner += [handler.body for handler in getattr(node, "handlers", [])]
        for block in inner:
            if isinstance(block, list):
                out.extend(_module_level(block))
    return out


def import_graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports at module level."""
    modules = project_modules()
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        for node in _module_level(ast.parse(path.read_text()).body):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in modules else node.module
                           for a in node.names]
            graph[name].update(t for t in targets if t in modules and t != name)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A cycle of the graph as a list of modules, or None."""
    state: dict[str, int] = {}  # 1 on the stack, 2 done
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return [*stack[stack.index(nxt):], nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def test_no_module_level_import_cycle() -> None:
    graph = import_graph()
    assert len(graph) > 60 and "sbagents.core.backends" in graph["sbagents.pipeline.backends"]
    assert find_cycle(graph) is None, " -> ".join(find_cycle(graph) or [])


def test_the_cycle_finder_finds_a_cycle() -> None:
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_sb3_training_does_not_load_the_rllib_backend() -> None:
    code = ("import sys, sbagents.train, sbagents.api\n"
            "print(sorted(m for m in sys.modules if m.startswith(('sbagents.rllib', 'ray'))))\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and result.stdout.strip() == "[]", result.stdout + result.stderr
