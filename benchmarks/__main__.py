"""``python -m benchmarks``: run the benchmark suite and update ``BENCHMARKS.md``.

Suites write their Markdown between their own markers (``<!-- speed:start -->`` / ``<!-- speed:end -->``),
so other sections of the file stay. ``--quick`` runs shorter measurements (a smoke run, noisier numbers).
"""

from __future__ import annotations

import argparse

from benchmarks import speed


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__.splitlines()[0])
    parser.add_argument("--output", default="BENCHMARKS.md", help="Markdown file to update")
    parser.add_argument("--json", default="benchmarks/results/speed.json", help="raw results ('' to skip)")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds per figure (median)")
    parser.add_argument("--quick", action="store_true", help="short measurements (smoke run)")
    args = parser.parse_args(argv)
    speed.main(output=args.output, json_path=args.json or None, rounds=args.rounds, quick=args.quick)


if __name__ == "__main__":
    main()
