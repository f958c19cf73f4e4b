"""``python -m benchmarks``: list, run and render the benchmarks of ``BENCHMARKS.md``.

    python -m benchmarks list                      # every benchmark: name, kind, results file, what it measures
    python -m benchmarks run NAME [OPTIONS...]     # measure, save its results file, update its section
    python -m benchmarks run NAME --help           # the benchmark's own options (budgets, seeds, rounds)
    python -m benchmarks render NAME [NAME...]     # rebuild sections from their results files (no measuring)
    python -m benchmarks render --all [--check]    # every section; --check: exit 1 if any would change

``run`` and ``render`` take ``--output FILE`` (default ``BENCHMARKS.md``) before the name; ``run --results FILE``
saves the results elsewhere (a scratch run that leaves ``benchmarks/results`` alone).

A smoke run (``--quick``, ``--smoke`` or ``--tiny`` among the benchmark's options,
:data:`~benchmarks.harness.SMOKE_FLAGS`) never writes the published results: its results go to a scratch file in a
new temporary folder (or ``--results FILE``), the section is written only to an ``--output FILE`` given, and naming
the published results file or ``BENCHMARKS.md`` for it is refused in one line (exit 2).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

from benchmarks.harness import Benchmark, registry
from benchmarks.report import MARKDOWN, atomic_write_text, read_section, replace_section, save_results


def build_parser() -> argparse.ArgumentParser:
    """The ``list`` / ``run`` / ``render`` sub-commands."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=(__doc__ or "").splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="every benchmark with its kind, results file and section")
    run = sub.add_parser("run", help="measure one benchmark, save its results and update its section")
    run.add_argument("--output", default=None,
                     help="Markdown file to update ('' to skip; default BENCHMARKS.md, none for a smoke run)")
    run.add_argument("--results", default=None,
                     help="results file (default: the benchmark's own; a scratch file for a smoke run)")
    run.add_argument("name", help="benchmark name (see `list`)")
    run.add_argument("options", nargs=argparse.REMAINDER, help="the benchmark's own options")
    render = sub.add_parser("render", help="rebuild sections from their results files")
    render.add_argument("--output", default=str(MARKDOWN), help="Markdown file to update")
    render.add_argument("--all", action="store_true", help="every benchmark")
    render.add_argument("--check", action="store_true", help="change nothing; exit 1 if a section would change")
    render.add_argument("names", nargs="*", help="benchmark names (see `list`)")
    return parser


def _published(bench: Benchmark, results: str | None, output: str | None) -> str | None:
    """Which published file (the benchmark's results file, ``BENCHMARKS.md``) ``--results`` / ``--output`` name,
    if any."""
    if results and Path(results).resolve() == bench.results_path.resolve():
        return f"results file {bench.results_path.name}"
    if output and Path(output).resolve() == MARKDOWN.resolve():
        return MARKDOWN.name
    return None


def _pick(benchmarks: dict[str, Benchmark], names: Sequence[str]) -> list[Benchmark]:
    unknown = [n for n in names if n not in benchmarks]
    if unknown:
        raise SystemExit(f"error: unknown benchmark {', '.join(unknown)}; known: {', '.join(benchmarks)}")
    return [benchmarks[n] for n in names]


def list_benchmarks(benchmarks: dict[str, Benchmark], markdown: Path = MARKDOWN) -> str:
    """The ``list`` table: name, kind, results file (and whether it exists), summary."""
    rows = [("name", "kind", "results", "what it measures")]
    for b in benchmarks.values():
        missing = "" if b.results_path.exists() else " (not yet run)" if b.pending else " (missing)"
        rows.append((b.name, b.kind, b.results + missing, b.summary))
    widths = [max(len(r[i]) for r in rows) for i in range(3)]
    lines = [f"{r[0]:<{widths[0]}}  {r[1]:<{widths[1]}}  {r[2]:<{widths[2]}}  {r[3]}" for r in rows]
    return "\n".join(lines) + f"\n{len(benchmarks)} benchmarks; sections in {markdown.name}"


def render_into(text: str, chosen: Sequence[Benchmark]) -> str:
    """``text`` with each chosen benchmark's section replaced by its rendering from its results file."""
    for bench in chosen:
        text = replace_section(text, bench.render_file(), bench.name)
    return text


def _check_results(chosen: Sequence[Benchmark]) -> None:
    missing = [b for b in chosen if not b.results_path.is_file()]
    if missing:
        names = ", ".join(f"{b.name} ({b.results})" for b in missing)
        raise SystemExit(f"error: no results file for {names} in benchmarks/results; measure with "
                         f"`python -m benchmarks run {missing[0].name}`")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command; return the exit status (1: ``render --check`` found a stale section)."""
    args = build_parser().parse_args(argv)
    benchmarks = registry()
    if args.command == "list":
        print(list_benchmarks(benchmarks))
        return 0
    if args.command == "run":
        (bench,) = _pick(benchmarks, [args.name])
        smoke = bench.is_smoke(args.options)
        if smoke:
            published = _published(bench, args.results, args.output)
            if published is not None:
                print(f"python -m benchmarks: error: a smoke run ({' / '.join(bench.smoke_flags)}) never writes the "
                      f"published {published}; give --results and --output files elsewhere (or leave them out)",
                      file=sys.stderr)
                return 2
        results = bench.run(args.options)
        if args.results:
            path = Path(args.results)
        elif smoke:
            path = Path(tempfile.mkdtemp(prefix=f"benchmarks-{bench.name}-")) / Path(bench.results).name
        else:
            path = bench.results_path
        (bench.save or save_results)(results, path)
        if args.output is None and not smoke:
            args.output = str(MARKDOWN)
        if args.output:
            output = Path(args.output)
            old = output.read_text() if output.exists() else "# Benchmarks\n"
            atomic_write_text(output, replace_section(old, bench.render(results), bench.name))
        print(f"{bench.name}: results -> {path}" + (f", section -> {args.output}" if args.output else "")
              + (" (smoke run: the published results and BENCHMARKS.md are left alone)" if smoke else ""))
        return 0
    if not args.all and not args.names:
        raise SystemExit("error: render needs benchmark names or --all")
    chosen = [b for b in benchmarks.values() if not b.pending] if args.all else _pick(benchmarks, args.names)
    _check_results(chosen)
    output = Path(args.output)
    old = output.read_text() if output.exists() else "# Benchmarks\n"
    new = render_into(old, chosen)
    if args.check:
        stale = [b.name for b in chosen if read_section(output, b.name) is None
                 or replace_section(old, b.render_file(), b.name) != old]
        if stale:
            print(f"stale sections in {output}: {', '.join(stale)} (run `python -m benchmarks render NAME`)")
            return 1
        print(f"{len(chosen)} sections up to date in {output}")
        return 0
    if new != old:
        atomic_write_text(output, new)
    print(f"rendered {len(chosen)} sections into {output}" + ("" if new != old else " (no change)"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
