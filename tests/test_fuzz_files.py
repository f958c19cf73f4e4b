"""Fuzzing as a test: seeded mutations of a run dir's files, each read by its command in a process of its own.

A bounded run of the harness of ``benchmarks/suites/fuzz.py`` (``python -m benchmarks run fuzz`` is the long one):
:data:`CASES_PER_KIND` cases of each file kind (model zips, VecNormalize statistics, replay buffers,
``evaluations.npz``, configs, monitor CSVs), seed :data:`SEED`. Allowed outcomes: loaded (exit 0) or refused in one
line (exit 2). Never a signal, a traceback, more than 500 MiB resident, a file written outside the case's folder, a
command run. A failing case names its seed and number: ``python -m benchmarks run fuzz --seed 0 --case I --keep DIR``
keeps its folder, with the command to run there.
"""

from __future__ import annotations

import random
import zipfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from benchmarks.suites.fuzz import (
    ALLOWED,
    KINDS,
    MEMORY_LIMIT_MIB,
    Case,
    Fuzzer,
    Mutator,
    Outcome,
    classify,
    fuzzer,
    markdown,
    read_zip,
    record,
)
from benchmarks.suites.fuzz import empty_results as fuzz_results

SEED = 0
CASES_PER_KIND = 5


@pytest.fixture(scope="module")
def fz(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Fuzzer]:
    """Seed runs trained, workers warmed up (~30 s here, once for the file); cases without zip bombs (the benchmark
    makes them: each costs seconds)."""
    with fuzzer(tmp_path_factory.mktemp("fuzz"), timeout=60, bombs=False) as prepared:
        yield prepared


def describe(case: Case, outcome: Outcome) -> str:
    return (f"case {case.index} of seed {case.seed} ({case.kind}, {case.file}): {outcome.outcome} {outcome.detail}\n"
            f"  mutations: {'; '.join(case.mutations)}\n  command: {case.command()}\n  stderr: {outcome.stderr_tail}")


def test_the_files_as_trained_load(fz: Fuzzer) -> None:
    """Each command exits 0 on the unmutated runs, under the memory limit also in a new interpreter: the refusals
    below are the mutations' doing."""
    assert len(fz.clean) == 4
    for case, outcome, fresh_mib in fz.clean:
        assert outcome.outcome == "ok", describe(case, outcome)
        assert 0 < fresh_mib < MEMORY_LIMIT_MIB and outcome.maxrss_mib >= outcome.forked_mib > 0


@pytest.mark.parametrize("kind", KINDS)
def test_mutated_files_load_or_are_refused_in_one_line(fz: Fuzzer, kind: str) -> None:
    failures, outcomes = [], []
    for n in range(CASES_PER_KIND):
        case, outcome = fz.case(SEED, n * len(KINDS) + KINDS.index(kind))
        assert case.kind == kind and case.mutations
        outcomes.append(outcome.outcome)
        if outcome.failed:
            failures.append(describe(case, outcome))
    assert not failures, "\n".join(failures)
    assert set(outcomes) <= set(ALLOWED)


@pytest.mark.parametrize(("script", "expected"), [
    ("pass", "ok"),
    ("import sys; print('prog: error: bad file', file=sys.stderr); sys.exit(2)", "refused"),
    ("import sys; print('a warning', file=sys.stderr); print('prog: error: bad', file=sys.stderr); sys.exit(2)",
     "not-one-line"),
    ("raise ValueError('boom')", "traceback"),
    ("import sys; sys.exit(3)", "bad-exit"),
    ("import os, signal; os.kill(os.getpid(), signal.SIGSEGV)", "signal"),
    ("data = b'x' * (600 << 20)", "memory"),
    ("open(OUTSIDE + '/written', 'w').write('x')", "outside-write"),
    ("import os; os.rename('here', OUTSIDE + '/moved')", "outside-write"),
    ("import os; os.system('true')", "code-exec"),
    ("import time; time.sleep(30)", "timeout"),
])
def test_the_harness_tells_each_outcome(fz: Fuzzer, tmp_path: Path, script: str, expected: str) -> None:
    """The classifier on real processes: a crash, memory, a write outside the case's folder, a command run."""
    case_dir = fz.folder / "cases" / "self-test"
    case_dir.mkdir(parents=True, exist_ok=True)
    (case_dir / "here").write_text("x")
    path = case_dir / "script.py"
    path.write_text(f"OUTSIDE = {str(fz.folder / 'outside')!r}\n{script}\n")
    outcome = fz.check([str(path)], case_dir, worker="sbagents.plot", timeout=2 if expected == "timeout" else 30)
    assert outcome.outcome == expected, (outcome, script)
    for leftover in (fz.folder / "outside").iterdir():
        leftover.unlink()


def test_a_write_in_the_sandbox_outside_the_case_is_seen_without_the_hook(fz: Fuzzer) -> None:
    """A write the audit hook cannot see (a shell's) still shows in the sandbox compared before and after; and the
    command that made it is reported first."""
    case_dir = fz.folder / "cases" / "self-test-shell"
    case_dir.mkdir(parents=True, exist_ok=True)
    path = case_dir / "script.py"
    path.write_text(f"import subprocess\nsubprocess.run(['sh', '-c', 'echo x > {fz.folder / 'home' / 'x'}'])\n")
    outcome = fz.check([str(path)], case_dir, worker="sbagents.plot")
    assert outcome.outcome == "code-exec" and "sh" in outcome.detail
    assert classify(0, "", 100.0, changed=["SANDBOX/home/x"])[0] == "outside-write"
    (fz.folder / "home" / "x").unlink()


def test_mutations_are_seeded_and_change_the_file(fz: Fuzzer) -> None:
    """The same seed gives the same bytes (a failure is reproducible); a model zip's members are mutated inside."""
    model = fz.folder / "seeds" / "ddpg" / "logs" / "ddpg" / "sbagents_SmartHome-v0_1" / "sbagents_SmartHome-v0.zip"
    original = model.read_bytes()
    for seed in range(20):
        first = Mutator(random.Random(seed), fz.folder / "outside", bombs=False).mutate("model", original)
        assert first == Mutator(random.Random(seed), fz.folder / "outside", bombs=False).mutate("model", original)
    members = [read_zip(Mutator(random.Random(s), fz.folder / "outside", bombs=False).mutate("model", original))
               for s in range(40)]
    assert sum(m is not None for m in members) > 20  # most stay zips: the members inside are what changed
    with zipfile.ZipFile(model) as archive:
        assert "data" in archive.namelist()


def test_the_section_lists_failures_with_their_seed() -> None:
    results = fuzz_results(7, 2, 120.0, KINDS)
    results |= {"machine": {"cpu": "cpu", "cores": 2}, "command": "python -m benchmarks run fuzz --seed 7",
                "seconds": 60.0}
    record(results, Case(7, 0, "model", "logs/x.zip", ["-m", "sbagents.evaluate"], ["data: set ['gamma'] = 1e999"]),
           Outcome("refused", 2, 380.0, 0.1, "python -m sbagents.evaluate: error: bad"))
    record(results, Case(7, 1, "vecnormalize", "logs/v.npz", ["-m", "sbagents.evaluate"], ["obs_rms|mean"]),
           Outcome("signal", -11, 390.0, 0.1, "", "SIGSEGV"))
    text = markdown(results)
    assert "| model | evaluate -n 1 | 1 | 0 | 1 | 0 | 380 MiB |" in text
    assert "| vecnormalize | evaluate -n 1 | 1 | 0 | 0 | 1 | 390 MiB |" in text
    assert "| 1 | logs/v.npz | signal (SIGSEGV) | obs_rms\\|mean |" in text
    assert "--seed 7 --case I --keep DIR" in text and markdown(results) == text
