"""``python -m sbagents.plot``: learning curves of finished (or running) runs as a PNG.

Parses the flags and calls :func:`sbagents.visualize.curves.plot`.
"""

from __future__ import annotations

import sys

from sbagents.cli_common import ArgumentParser, add_run_arguments, run, run_ref
from sbagents.visualize.curves import plot


def build_parser() -> ArgumentParser:
    """The ``plot`` argument parser."""
    p = ArgumentParser(prog="python -m sbagents.plot", description="Plot learning curves of runs to a PNG.")
    add_run_arguments(p, required=False, exp_id=False, load_best=False, trust=False)
    p.add_argument("-o", "--output", default=None, help="PNG file (default: <log-folder>/learning_curves.png)")
    p.add_argument("--x", dest="x_axis", default="timesteps", choices=["timesteps", "episodes"], help="x axis")
    p.add_argument("--window", type=int, default=0, help="moving-average window in episodes (0: automatic)")
    p.add_argument("--title", default=None, help="figure title")
    return p


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv``, plot, print the PNG path (and one warning line per file that could not be read)."""
    args = build_parser().parse_args(argv)
    notes: list[str] = []
    try:
        path = plot(run_ref(args), args.output, args.x_axis, args.window, args.title, notes)
    finally:
        for note in notes:
            print(f"python -m sbagents.plot: warning: {note}", file=sys.stderr)
    print(f"plot: {path}")
    return 0


if __name__ == "__main__":
    run("python -m sbagents.plot", main)
