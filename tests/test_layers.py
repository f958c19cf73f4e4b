"""The layers of docs/architecture.md hold, imports inside functions included: ``lint-imports`` keeps every contract
of pyproject.toml, and the packages of sbagents import each other in no cycle."""

from __future__ import annotations

import subprocess
import sys

import grimp
from cli_helpers import REPO
from test_import_graph import find_cycle

if sys.version_info >= (3, 11):
    import tomllib
else:  # import-linter installs tomli on older Pythons
    import tomli as tomllib


def _contract(contract_id: str) -> dict[str, object]:
    """The import-linter contract ``contract_id`` of pyproject.toml."""
    config = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"]
    return next(c for c in config["contracts"] if c.get("id") == contract_id)


def package_graph() -> dict[str, set[str]]:
    """Package (``sbagents.<name>``) -> the packages it imports, counting imports inside functions and under
    ``if TYPE_CHECKING:``, without the imports the no-cycle contract ignores (each says why)."""
    graph = grimp.build_graph("sbagents", exclude_type_checking_imports=False, cache_dir=None)
    for expression in _contract("no-package-cycles").get("ignore_imports", []):  # type: ignore[attr-defined]
        importer, _, imported = str(expression).partition(" -> ")
        graph.remove_import(importer=importer, imported=imported)
    packages: dict[str, set[str]] = {}
    for module in graph.modules:
        source = ".".join(module.split(".")[:2])
        targets = {".".join(t.split(".")[:2]) for t in graph.find_modules_directly_imported_by(module)}
        packages.setdefault(source, set()).update(t for t in targets if t != source and t != "sbagents")
    return packages


def test_lint_imports_keeps_every_contract() -> None:
    code = "from importlinter.cli import lint_imports_command; lint_imports_command()"
    result = subprocess.run([sys.executable, "-c", code, "--no-cache", "--no-logo"], cwd=REPO, capture_output=True,
                            text=True, timeout=600)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
    assert "0 broken" in result.stdout and _contract("layers")["type"] == "layers"


def test_no_package_cycle_counting_imports_inside_functions() -> None:
    graph = package_graph()
    assert {"sbagents.core", "sbagents.pipeline", "sbagents.multiagent", "sbagents.envs"} <= set(graph)
    assert "sbagents.core" in graph["sbagents.pipeline"]
    assert find_cycle(graph) is None, " -> ".join(find_cycle(graph) or [])


def test_the_callbacks_take_info_keys_without_loading_pettingzoo() -> None:
    code = ("import sys, sbagents.callbacks.safety, sbagents.callbacks.transparency\n"
            "print(sorted(m for m in sys.modules if m.startswith(('pettingzoo', 'sbagents.multiagent', "
            "'sbagents.pipeline'))))\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and result.stdout.strip() == "[]", result.stdout + result.stderr


def test_the_feature_packages_are_independent_except_where_declared() -> None:
    """Every package of the feature layer is in the independence contract, and each import between two of them is
    declared (an ``ignore_imports`` line with its reason) rather than allowed by the layer."""
    contract = _contract("feature-packages-independent")
    layers = _contract("layers")["layers"]
    feature_layer = next(layer for layer in layers if "multiagent" in layer)  # type: ignore[attr-defined]
    names = {f"sbagents.{name.strip()}" for name in feature_layer.replace("|", ":").split(":")}
    assert contract["type"] == "independence" and set(contract["modules"]) == names  # type: ignore[arg-type]
    graph = grimp.build_graph("sbagents", exclude_type_checking_imports=False, cache_dir=None)
    declared = [str(e).partition(" -> ") for e in contract["ignore_imports"]]  # type: ignore[attr-defined]

    def matches(pattern: str, module: str) -> bool:
        return module == pattern or (pattern.endswith(".**") and module.startswith(pattern[:-3] + "."))

    undeclared = []
    for importer in names:
        for imported in names - {importer}:
            for module in graph.find_descendants(importer) | {importer}:
                for target in graph.find_modules_directly_imported_by(module):
                    if (target == imported or target.startswith(imported + ".")) and not any(
                            matches(src, module) and (matches(dst, target) or dst == target)
                            for src, _, dst in declared):
                        undeclared.append(f"{module} -> {target}")
    assert undeclared == []
