"""The benchmark protocol and its registry.

A benchmark is a :class:`Benchmark`: a name (also its section marker in ``BENCHMARKS.md``), a kind (the folder
its module lives in: ``speed``, ``learning`` or ``suites``), a results file under ``benchmarks/results/``, a
``run(argv) -> results`` that measures (parsing its own options, so ``run NAME --help`` documents them) and a
``render(results) -> markdown`` that makes the section from the results alone. A module of
``benchmarks/speed``, ``benchmarks/learning`` or ``benchmarks/suites`` declares its benchmarks in a module-level
``BENCHMARKS`` tuple; :func:`registry` finds them, so adding a benchmark touches no other file.

Modules import only what ``pip install -e ".[test]"`` installs at module level; optional packages (EnvPool,
Ray, Flower, rliable, panda-gym) are imported inside the functions that need them, so ``list`` and ``render``
work everywhere.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from benchmarks.report import RESULTS_DIR, load_results

#: The kinds of benchmarks, each a subpackage of ``benchmarks``.
KINDS: tuple[str, ...] = ("speed", "learning", "suites")
#: The options that make a run a smoke run (a check that the benchmark runs end to end, with numbers that mean
#: nothing): its results never replace the published ones (see :meth:`Benchmark.is_smoke`).
SMOKE_FLAGS: tuple[str, ...] = ("--quick", "--smoke", "--tiny")


@dataclass(frozen=True)
class Benchmark:
    """One measured section of ``BENCHMARKS.md``.

    :param name: CLI name and section marker (``<!-- name:start -->``).
    :param kind: one of :data:`KINDS`; the subpackage the module lives in.
    :param results: results file, relative to ``benchmarks/results/``.
    :param summary: one line for ``python -m benchmarks list``.
    :param run: measures with the benchmark's own command-line options and returns the results (JSON-able);
        the harness saves them to :attr:`results` and renders the section.
    :param render: results -> the section's Markdown (without the markers); pure: no clock, no git, no
        machine state, so rendering twice gives the same bytes.
    :param load: reads the results file (JSON by default).
    :param save: writes the results file (indented JSON by default).
    :param command: how to run it, shown by ``list`` (default ``python -m benchmarks run NAME``).
    :param smoke_flags: the benchmark's options that make a smoke run (default :data:`SMOKE_FLAGS`): ``run``
        then writes its results to a scratch file and leaves ``BENCHMARKS.md`` alone unless told other files.
    :param pending: its measurement (hours long) has not been made yet: it has no results file and no section until
        its first run, after which the flag goes (``tests/test_benchmarks_harness.py`` holds both to that).
    """

    name: str
    kind: str
    results: str
    summary: str
    run: Callable[[Sequence[str]], Any]
    render: Callable[[Any], str]
    load: Callable[[Path], Any] = field(default=load_results)
    save: Callable[[Any, Path], None] | None = None
    command: str = ""
    smoke_flags: tuple[str, ...] = SMOKE_FLAGS
    pending: bool = False

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"benchmark {self.name!r}: kind {self.kind!r} is not one of {', '.join(KINDS)}")

    @property
    def results_path(self) -> Path:
        """Absolute path of the results file."""
        return RESULTS_DIR / self.results

    def is_smoke(self, options: Sequence[str]) -> bool:
        """Whether ``options`` (the benchmark's own) ask for a smoke run: one of :attr:`smoke_flags`, or an
        abbreviation of one that argparse would accept (``--qui``), before a ``--`` that ends the options."""
        for option in options:
            if option == "--":
                break
            name = option.partition("=")[0]
            if name.startswith("--") and len(name) > 3 and any(flag.startswith(name) for flag in self.smoke_flags):
                return True
        return False

    def render_file(self, path: Path | None = None) -> str:
        """The section rendered from the results file (``path`` or :attr:`results_path`)."""
        return self.render(self.load(path or self.results_path))


def _modules(kind: str) -> list[str]:
    package = importlib.import_module(f"benchmarks.{kind}")
    return sorted(f"benchmarks.{kind}.{m.name}" for m in pkgutil.iter_modules(package.__path__))


def registry() -> dict[str, Benchmark]:
    """Every benchmark, by name (modules of :data:`KINDS` in name order, each module's ``BENCHMARKS`` in order).

    :raises ValueError: two benchmarks share a name, or one's kind differs from its folder.
    """
    found: dict[str, Benchmark] = {}
    for kind in KINDS:
        for module_name in _modules(kind):
            module = importlib.import_module(module_name)
            for bench in getattr(module, "BENCHMARKS", ()):
                if bench.name in found:
                    raise ValueError(f"benchmark name {bench.name!r} declared twice ({module_name})")
                if bench.kind != kind:
                    raise ValueError(f"benchmark {bench.name!r} has kind {bench.kind!r} but lives in "
                                     f"benchmarks/{kind}")
                found[bench.name] = bench
    return found
