"""README.md and the docs stay true where it can be checked: the README opens with the two fresh-machine commands,
every link to a file or a heading (BENCHMARKS.md's sections included) lands, and the README's module map names the
packages and modules of today's tree."""

from __future__ import annotations

import re
import unicodedata
from pathlib import Path

import pytest
from cli_helpers import REPO

README = REPO / "README.md"
#: README command 1 (install + the main job) and command 2 (install + the whole suite), in this order, first.
COMMANDS = (
    "pip install torch==2.13.0 && pip install . && python -m sbagents.train",
    'pip install torch==2.13.0 && pip install -e ".[test]" && python -m pytest -n auto --dist loadfile',
)
#: The pages whose links are checked.
PAGES = [README, REPO / "docs" / "architecture.md", REPO / "docs" / "extending.md"]


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped (``-`` and ``_`` kept), spaces -> ``-``."""
    kept = [ch for ch in heading.strip().lower() if ch in " -_" or unicodedata.category(ch)[0] in "LNM"]
    return "".join(kept).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """Every heading anchor of ``page`` (repeated headings get ``-1``, ``-2``, ... as on GitHub)."""
    text = re.sub(r"^```.*?^```", "", page.read_text(), flags=re.S | re.M)  # no headings inside code blocks
    seen: dict[str, int] = {}
    found = set()
    for match in re.finditer(r"^#{1,6} (.+?)\s*$", text, flags=re.M):
        base = slug(match.group(1))
        count = seen.get(base, 0)
        seen[base] = count + 1
        found.add(f"{base}-{count}" if count else base)
    return found


def links(page: Path) -> list[str]:
    """The targets of the Markdown links and images of ``page`` (outside code blocks)."""
    text = re.sub(r"^```.*?^```", "", page.read_text(), flags=re.S | re.M)
    return re.findall(r"\]\(([^)\s]+)\)", text)


def test_the_readme_opens_with_the_two_commands() -> None:
    text = README.read_text()
    blocks = re.findall(r"```bash\n(.*?)\n```", text, flags=re.S)
    assert tuple(blocks[:2]) == COMMANDS
    before = text[:text.index("```bash")]
    assert before.strip() == "# sbagents", "nothing but the title comes before the two commands"


def test_the_slug_is_githubs() -> None:
    assert slug("GridWorld: the default `python -m sbagents.train`") == "gridworld-the-default-python--m-sbagentstrain"
    assert slug("texas hold'em (limit, 2 players): self-play MaskablePPO") == \
        "texas-holdem-limit-2-players-self-play-maskableppo"
    assert slug("Fast vector envs (`--vec-env`)") == "fast-vector-envs---vec-env"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_link_lands(page: Path) -> None:
    broken = []
    for target in links(page):
        if re.match(r"[a-z]+:", target):  # https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        file = (page.parent / path).resolve() if path else page
        if not file.exists():
            broken.append(f"{target}: no file {file}")
        elif anchor and (file.suffix != ".md" or anchor not in anchors(file)):
            broken.append(f"{target}: no heading #{anchor} in {file.name}")
    assert not broken, "\n".join(broken)


def test_the_readme_links_to_benchmark_sections_not_only_the_page() -> None:
    assert len(re.findall(r"\(BENCHMARKS\.md#[^)]+\)", README.read_text())) >= 20


def _readme_map() -> list[str]:
    text = README.read_text()
    start = text.index("## Documentation and module map")
    block = re.search(r"```\n(sbagents/.*?)```", text[start:], flags=re.S)
    assert block is not None, "the module map block"
    return block.group(1).splitlines()


def test_the_readme_module_map_names_every_package() -> None:
    lines = _readme_map()
    named = {m.group(1) for line in lines for m in re.finditer(r"sbagents/(\w+)/", line)}
    packages = {p.name for p in (REPO / "sbagents").iterdir()
                if p.is_dir() and not p.is_symlink() and (p / "__init__.py").exists()}
    assert packages <= named, f"missing from README's module map: {sorted(packages - named)}"
    assert named <= packages, f"not packages of sbagents/: {sorted(named - packages)}"
    assert any(line.startswith("envs/ callbacks/ zoo_configs/") for line in lines)


def test_the_readme_module_map_puts_modules_where_they_are() -> None:
    wrong, package = [], None
    for line in _readme_map():
        head = re.match(r"sbagents/(\w+)/", line)
        if head:
            package = REPO / "sbagents" / head.group(1)
        elif re.match(r"sbagents/\w+\.py", line):
            package = REPO / "sbagents"
        elif not line.startswith(" "):
            package = None
        if package is None:
            continue
        # top-level lines: the names before the description; package lines: every name, description included
        named = line.split("   ")[0] if package == REPO / "sbagents" else line
        for name in re.findall(r"\b(\w+\.py)\b", named):
            if not (package / name).exists():
                wrong.append(f"{name} is not in {package.relative_to(REPO)}")
    assert not wrong, wrong
