"""The seams of docs/architecture.md stay seams: the pipeline names no training feature beyond registering it, and
code tells env kinds apart by dispatching on the kind object, not by testing flags (counted in code tokens, so
docstrings, comments and messages do not count)."""

from __future__ import annotations

import io
import re
import tokenize
from pathlib import Path

import pytest
from cli_helpers import REPO

#: Feature -> a pattern of the code names that mention it.
FEATURES = {
    "robust": r"robust",
    "dp/privacy": r"^dp_|_dp_|_dp$|^dp$|privacy|private",
    "constrained": r"constrain",
    "replay buffer saving": r"replay_buffer",
    "games/self-play": r"selfplay|self_play|^games?$",
}
#: How often the pipeline and the train CLI may name a feature (the built-in extensions are named in
#: sbagents.registration; the game kind's three pipeline hooks import sbagents.games in pipeline/kinds.py and
#: pipeline/evaluation.py).
LIMIT = 3


def code_names(path: Path) -> list[str]:
    """The NAME tokens of a module (no strings, comments or docstrings)."""
    return [tok.string for tok in tokenize.generate_tokens(io.StringIO(path.read_text()).readline)
            if tok.type == tokenize.NAME]


def code_lines(path: Path) -> list[str]:
    """The module's lines with strings and comments blanked."""
    source = path.read_text()
    lines = source.splitlines()
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type in (tokenize.STRING, tokenize.COMMENT) and tok.start[0] == tok.end[0]:
            row = tok.start[0] - 1
            lines[row] = lines[row][:tok.start[1]] + " " * (tok.end[1] - tok.start[1]) + lines[row][tok.end[1]:]
    return lines


def package_modules() -> list[Path]:
    """Every module of the package once (envs/ and callbacks/ at the root, not through the links)."""
    links = ("envs", "callbacks", "zoo_configs")
    found = [p for p in (REPO / "sbagents").rglob("*.py") if p.relative_to(REPO / "sbagents").parts[0] not in links]
    return found + list((REPO / "envs").rglob("*.py")) + list((REPO / "callbacks").rglob("*.py"))


@pytest.mark.parametrize("feature", list(FEATURES))
def test_the_pipeline_names_features_only_to_register_them(feature: str) -> None:
    files = [*sorted((REPO / "sbagents" / "pipeline").glob("*.py")), REPO / "sbagents" / "train.py"]
    hits = [f"{f.name}:{name}" for f in files for name in code_names(f) if re.search(FEATURES[feature], name, re.I)]
    assert len(hits) <= LIMIT, hits


def test_env_kinds_are_dispatched_on_not_tested() -> None:
    old_flags = re.compile(r"(?<![\w.])(?:ref|env_ref)\.(?:multi_agent|game)\b"
                           r"|\b(?:run|loaded)\.env\.(?:multi_agent|game)\b")
    kind_tests = re.compile(r"\.kind\.(?:masked|pettingzoo|image_wrapper)\b|\w*ref\.kind is\b")
    old, tests = [], []
    for path in package_modules():
        for number, line in enumerate(code_lines(path), 1):
            where = f"{path.relative_to(REPO)}:{number}"
            old += [where] * len(old_flags.findall(line))
            tests += [where] * len(kind_tests.findall(line))
    assert not old, f"EnvRef has no multi_agent/game flags any more: {old}"
    assert len(tests) <= 5, tests


def test_the_docs_capability_table_is_the_algorithm_table() -> None:
    from sbagents.algos import capability_table

    page = (REPO / "docs" / "architecture.md").read_text()
    start, end = "<!-- capability-table:start -->\n", "\n<!-- capability-table:end -->"
    shown = page[page.index(start) + len(start):page.index(end)]
    assert shown == capability_table(markdown=True), "docs/architecture.md's table differs; paste:\n" + \
        capability_table(markdown=True)
