"""The benchmark harness: one registry, every BENCHMARKS.md section rendered from its results file, honest stats.

``python -m benchmarks render --all`` must leave BENCHMARKS.md byte-identical: each section is exactly what its
benchmark renders from the results file in ``benchmarks/results/``, so no figure in it is typed by hand.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from benchmarks import __main__ as harness_cli
from benchmarks.harness import KINDS, Benchmark, registry
from benchmarks.report import MARKDOWN, RESULTS_DIR, read_section, section_names

TEXT = MARKDOWN.read_text()


def test_every_section_has_one_benchmark_and_every_benchmark_a_section() -> None:
    """... except a pending benchmark (a long measurement not made yet), which has neither results nor section."""
    benchmarks = {name: b for name, b in registry().items() if not b.pending}
    sections = section_names(TEXT)
    assert len(sections) == len(set(sections)), "a section marker is repeated"
    assert sorted(sections) == sorted(benchmarks)
    for pending in (b for b in registry().values() if b.pending):
        assert not pending.results_path.exists(), f"{pending.name} has results: drop its pending flag"
    for bench in benchmarks.values():
        assert bench.kind in KINDS
        assert bench.results_path.is_file(), f"{bench.name}: results file {bench.results} missing"
        assert bench.results_path.resolve().is_relative_to(RESULTS_DIR)


def test_render_all_leaves_benchmarks_md_byte_identical() -> None:
    rendered = harness_cli.render_into(TEXT, [b for b in registry().values() if not b.pending])
    if rendered != TEXT:
        stale = [name for name in section_names(TEXT) if read_section(MARKDOWN, name)
                 != registry()[name].render_file()]
        pytest.fail(f"sections differ from their rendering: {stale} (python -m benchmarks render NAME)")
    assert rendered == TEXT


def test_render_is_deterministic() -> None:
    for bench in registry().values():
        if not bench.pending:
            assert bench.render_file() == bench.render_file(), bench.name


def test_headline_pointers_name_real_sections() -> None:
    """The ``section`` column of the headline table names sections that exist (comma-separated where several)."""
    table = TEXT.split("## Headline results", 1)[1].split("<!--", 1)[0]
    rows = [line for line in table.splitlines() if line.startswith("|") and not line.startswith("|---")][1:]
    assert rows, "no headline rows"
    sections = set(section_names(TEXT))
    for row in rows:
        pointer = row.strip().strip("|").split("|")[-1].strip()
        names = [n.strip() for n in pointer.split(",")]
        assert names and all(n in sections for n in names), f"headline pointer {pointer!r} names no section"


def test_list_shows_every_benchmark(capsys: pytest.CaptureFixture[str]) -> None:
    assert harness_cli.main(["list"]) == 0
    out = capsys.readouterr().out
    for name in registry():
        assert re.search(rf"^{re.escape(name)}\s", out, re.M), name
    assert f"{len(registry())} benchmarks" in out


def test_run_saves_results_and_renders_only_its_section(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``run NAME opts``: the benchmark parses its own options; the harness saves its results (atomically) and
    replaces its section, leaving the rest of the Markdown alone; ``render --check`` then finds it current."""
    seen: list[list[str]] = []

    def fake_run(argv: list[str]) -> dict[str, object]:
        seen.append(list(argv))
        return {"value": int(argv[1])}

    fake = Benchmark(name="fake", kind="speed", results="fake.json", summary="a test double",
                     run=fake_run, render=lambda r: f"## Fake\n\nvalue {r['value']}")
    monkeypatch.setattr(harness_cli, "registry", lambda: {"fake": fake})
    md = tmp_path / "B.md"
    md.write_text("# Benchmarks\n\n<!-- other:start -->\nkeep me\n<!-- other:end -->\n")
    results = tmp_path / "fake.json"
    code = harness_cli.main(["run", "--output", str(md), "--results", str(results), "fake", "--value", "7"])
    assert code == 0 and seen == [["--value", "7"]]
    assert results.read_text() == '{\n  "value": 7\n}\n'
    text = md.read_text()
    assert "keep me" in text and read_section(md, "fake") == "## Fake\n\nvalue 7"
    assert not list(tmp_path.glob(".*.tmp")), "a temporary file was left behind"
    monkeypatch.setattr(Benchmark, "results_path", property(lambda self: results))
    assert harness_cli.main(["render", "--output", str(md), "--check", "fake"]) == 0
    md.write_text(text.replace("value 7", "value 8"))
    assert harness_cli.main(["render", "--output", str(md), "--check", "fake"]) == 1
    assert harness_cli.main(["render", "--output", str(md), "fake"]) == 0
    assert read_section(md, "fake") == "## Fake\n\nvalue 7"


def test_unknown_benchmark_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        harness_cli.main(["render", "no-such-benchmark"])
    assert "unknown benchmark no-such-benchmark" in str(info.value.code)


def test_learning_sections_show_iqm_with_intervals() -> None:
    """Every learning benchmark over several seeds reports the IQM with its 95% interval beside mean +- std."""
    learning = [b for b in registry().values() if b.kind == "learning" and not b.pending]
    assert learning
    for bench in learning:
        section = bench.render_file()
        if re.search(r"\b1 seed\b", section):
            continue
        assert "IQM" in section and "95%" in section, f"{bench.name}: no IQM with an interval"


def test_seed_stats_are_reproducible_and_bracket_the_iqm() -> None:
    pytest.importorskip("rliable", reason="the bench extra: pip install -e '.[bench]'")
    from benchmarks.stats import format_iqm, seed_stats, stats_columns

    values = [4.75, 4.80, 4.90, 4.10, 4.95]
    first, second = seed_stats(values, reps=2000), seed_stats(values, reps=2000)
    assert first == second  # the bootstrap is seeded: sections stay byte-stable
    low, high = first["iqm_ci"]
    assert min(values) <= low <= first["iqm"] <= high <= max(values)
    # IQM of 5 values: rliable trims int(0.25 * 5) = 1 value at each end, the mean of the middle three
    assert first["iqm"] == pytest.approx((4.75 + 4.80 + 4.90) / 3)
    assert first["mean"] == pytest.approx(sum(values) / 5) and first["n"] == 5
    assert stats_columns(first)[0] == "4.75 / 4.80 / 4.90 / 4.10 / 4.95"
    assert format_iqm(first).startswith("4.82 [")
    one = seed_stats([3.0], reps=200)
    assert one["iqm_ci"] == [3.0, 3.0] and one["std"] == 0.0


def test_suite_time_parses_pytest_and_renders_ratios(monkeypatch: pytest.MonkeyPatch) -> None:
    from benchmarks.suites import suite_time

    assert suite_time.pytest_counts("....\n1115 passed, 27 skipped, 33 warnings in 1185.87s (0:19:45)\n") == {
        "passed": 1115, "skipped": 27}
    assert suite_time.pytest_counts("3 failed, 10 passed, 1 error in 2.0s") == {"failed": 3, "passed": 10,
                                                                                "error": 1}
    walls = iter([100.0, 40.0, 20.0, 100.0, 50.0, 40.0])

    def fake_time_suite(rev: str, args: list[str]) -> dict[str, object]:
        return {"rev": rev, "pytest_args": list(args), "wall_s": next(walls), "returncode": 0,
                "counts": {"passed": 3}}

    monkeypatch.setattr(suite_time, "time_suite", fake_time_suite)
    monkeypatch.setattr(suite_time, "_rev", lambda rev: rev[:7])
    results = suite_time.run(["--before", "aaaaaaaaa", "--after", "bbbbbbbbb"])
    assert [r["label"] for r in results["runs"]] == ["whole suite", "whole suite", "developer loop"]
    assert results["runs"][2]["pytest_args"] == ["-m", "not slow"]
    section = suite_time.render(results)
    assert "| aaaaaaa | whole suite | `-` | 3 passed | 0 | 100 | 1.00x |" in section
    assert "| bbbbbbb | whole suite | `-` | 3 passed | 0 | 40 | 2.50x |" in section
    assert "| bbbbbbb | developer loop | `-m not slow` | 3 passed | 0 | 20 | 5.00x |" in section
    assert results["command"] == "python -m benchmarks run suite-time --before aaaaaaa --after bbbbbbb"
    with_xdist = suite_time.run(["--before", "aaaaaaaaa", "--after", "bbbbbbbbb", "--xdist", "2", "--no-quick-loop"])
    assert [r["pytest_args"] for r in with_xdist["runs"]] == [[], [], ["-n", "2", "--dist", "loadfile"]]
    assert "--xdist 2 --no-quick-loop" in with_xdist["command"]


def test_render_without_results_file_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    fake = Benchmark(name="fake", kind="speed", results="no_such_file.json", summary="a test double",
                     run=lambda argv: {}, render=lambda r: "")
    monkeypatch.setattr(harness_cli, "registry", lambda: {"fake": fake})
    with pytest.raises(SystemExit) as info:
        harness_cli.main(["render", "--output", str(tmp_path / "B.md"), "fake"])
    assert str(info.value.code).startswith("error: no results file for fake (no_such_file.json)")
    assert not (tmp_path / "B.md").exists()
