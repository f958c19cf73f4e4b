"""docs/architecture.md's checkable claims hold for today's code: the layer list is pyproject.toml's contract, which
modules of the lowest layer import which, what the pipeline imports of the training extensions, which extensions
take runs of one model per group (and that such runs call no extension hook), the count of kind tests, and the
light modules (``lint-imports`` itself runs in tests/test_layers.py; the seams in tests/test_architecture.py)."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

from cli_helpers import REPO
from test_architecture import code_lines, package_modules

if sys.version_info >= (3, 11):
    import tomllib
else:  # import-linter installs tomli on older Pythons
    import tomli as tomllib

DOC = REPO / "docs" / "architecture.md"
SBAGENTS = REPO / "sbagents"


def doc() -> str:
    return DOC.read_text()


def imported_modules(path: Path) -> set[str]:
    """Every ``sbagents.*`` module ``path`` imports, anywhere (inside functions and ``if TYPE_CHECKING:`` too)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
    return {name for name in found if name.startswith("sbagents.")}


def top(name: str) -> str:
    """``sbagents.core.run_dir`` -> ``core``."""
    return name.split(".")[1]


def sources(target: str) -> list[Path]:
    """The source files of ``sbagents.<target>`` (a package or a module)."""
    folder = SBAGENTS / target
    return sorted(folder.rglob("*.py")) if folder.is_dir() else [SBAGENTS / f"{target}.py"]


def test_the_layer_list_is_the_import_linter_contract() -> None:
    config = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"]
    contract = next(c for c in config["contracts"] if c["id"] == "layers")
    expected = [{m.strip() for m in layer.split(":")} for layer in reversed(contract["layers"])]  # lowest first
    text = doc()
    block = text[text.index("<!-- layers:start -->"):text.index("<!-- layers:end -->")]
    items = re.split(r"^\d+\. ", block, flags=re.M)[1:]
    shown = [{name for name in re.findall(r"`(\w+)`", item)} for item in items]
    assert shown == expected
    assert all(":" in layer for layer in contract["layers"] if " " in layer.strip()), \
        "the doc says modules of one layer may import each other: ':' (not '|') separates them"


def _named_after(sentence_start: str) -> set[str]:
    """The backticked names of the doc's clause that starts with ``sentence_start`` (up to ``;`` or ``.``)."""
    text = " ".join(doc().split())
    clause = re.search(re.escape(sentence_start) + r"(.*?)[;.]", text)
    assert clause is not None, sentence_start
    return set(re.findall(r"`(\w+)`", clause.group(1)))


def test_what_core_and_extensions_import_is_what_the_doc_says() -> None:
    core = {top(m) for path in sources("core") for m in imported_modules(path)} - {"core"}
    assert core == _named_after("`core` imports")
    extensions = {top(m) for m in imported_modules(SBAGENTS / "extensions.py")}
    assert extensions == _named_after("`extensions` imports")


def test_what_the_pipeline_imports_of_the_training_extensions() -> None:
    """Only the names the doc lists: the trust extension's parsers (trust.py), the replay package's buffer files
    (training.py) and the datasets' writer and log reader (collecting.py, not training); no DP, robust, constrained,
    cloning or demonstration code,
    and runs of one model per group name no extension."""
    from sbagents.registration import TRAINING_EXTENSIONS

    extension_modules = {path.partition(":")[0] for path in TRAINING_EXTENSIONS}
    extension_packages = {m.rpartition(".")[0] for m in extension_modules} - {"sbagents.callbacks"}
    found = {}
    for path in sorted((SBAGENTS / "pipeline").glob("*.py")):
        hits = {m for m in imported_modules(path)
                if m in extension_modules or any(m.startswith(p + ".") or m == p for p in extension_packages)}
        if hits:
            found[path.name] = hits
    assert found == {"training.py": {"sbagents.replay.buffer_files"},
                     "trust.py": {"sbagents.callbacks.extension"},
                     "collecting.py": {"sbagents.datasets.writing", "sbagents.datasets.logs"}}


def test_one_training_path_for_one_model_or_one_per_group() -> None:
    """The doc: every run takes the same steps (train_sb3: _plan, _build, _learn, _finish, no branch), each model's
    hooks are called in a loop over the run's models, and no module holds a second sequence for group runs."""
    training = ast.parse((SBAGENTS / "pipeline" / "training.py").read_text())
    functions = {n.name: n for n in ast.walk(training) if isinstance(n, ast.FunctionDef)}
    assert not (SBAGENTS / "pipeline" / "team_training.py").exists()
    assert "_train_groups" not in functions
    train = functions["train_sb3"]
    assert not any(isinstance(n, ast.If) for n in ast.walk(train))
    called = [n.func.id for n in ast.walk(train) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)]
    assert [name for name in called if name.startswith("_")] == ["_plan", "_build", "_learn", "_finish"]

    def hooks(tree: ast.AST) -> set[str]:
        return {n.func.attr for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute)
                and isinstance(n.func.value, ast.Attribute) and n.func.value.attr == "extension"}

    model_hooks = {"callbacks", "finish", "judge"}
    assert model_hooks <= hooks(training)
    for name in ("_build", "_learn", "_finish"):  # each model's hooks sit in a loop over models
        loops = [n for n in ast.walk(functions[name]) if isinstance(n, ast.For | ast.comprehension)]
        assert any(hooks(loop) for loop in loops), name
    assert "specs.get(\"" not in ast.unparse(training)  # no spec is read by an extension's name


def test_the_extensions_that_refuse_group_runs() -> None:
    from sbagents.extensions import registered_extensions

    refuse = {e.name for e in registered_extensions() if not e.group_runs and e.__module__.startswith("sbagents.")}
    assert refuse == {"privacy", "robust", "constraint", "demos"}  # the doc: DP, robust, constrained, demonstrations


def test_the_count_of_kind_tests() -> None:
    """The doc: five today, four attribute reads and one identity test (tests/test_architecture.py's patterns)."""
    reads = re.compile(r"\.kind\.(?:masked|pettingzoo|image_wrapper)\b")
    identity = re.compile(r"\w*ref\.kind is\b")
    found: dict[str, list[str]] = {"reads": [], "identity": []}
    for path in package_modules():
        where = str(path.relative_to(SBAGENTS if path.is_relative_to(SBAGENTS) else REPO))
        for line in code_lines(path):
            found["reads"] += [where] * len(reads.findall(line))
            found["identity"] += [where] * len(identity.findall(line))
    assert sorted(found["reads"]) == ["core/env_names.py", "core/image_obs.py", "env_construction.py",
                                      "pipeline/models.py"]
    assert found["identity"] == ["play.py"]
    assert "There are five today: four attribute reads" in " ".join(doc().split())


def test_the_light_package_inits_import_nothing() -> None:
    for package in ("core", "pipeline", "deploy", "multiagent", "visualize"):
        tree = ast.parse((SBAGENTS / package / "__init__.py").read_text())
        imports = [ast.unparse(n) for n in ast.walk(tree) if isinstance(n, ast.Import | ast.ImportFrom)
                   and not (isinstance(n, ast.ImportFrom) and n.module == "__future__")]
        assert not imports, (package, imports)


def test_the_edge_modules_import_without_torch_sb3_or_gymnasium() -> None:
    code = ("import sys\n"
            "for m in ('torch', 'stable_baselines3', 'sb3_contrib', 'gymnasium'):\n"
            "    sys.modules[m] = None\n"
            "import sbagents.core.run_dir, sbagents.deploy.serving, sbagents.deploy.http_serving\n"
            "print('ok')\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert result.returncode == 0 and result.stdout.strip() == "ok", result.stderr[-2000:]
