"""``python -m sbagents.dashboard -f logs``: the operator's dashboard in a browser (runs, live curves, decisions,
safety, attacks, fairness, comparisons), read-only, on 127.0.0.1:8050 by default.

Parses the flags and calls :func:`sbagents.dashboard.server.serve`.
"""

from __future__ import annotations

from sbagents.cli_common import ArgumentParser, run
from sbagents.dashboard.server import DEFAULT_PORT, TOKEN_ENV_VAR, DashboardOptions, serve


def build_parser() -> ArgumentParser:
    """The ``dashboard`` argument parser."""
    p = ArgumentParser(prog="python -m sbagents.dashboard", description="Serve log folders as a read-only dashboard.")
    p.add_argument("-f", "--log-folder", dest="folders", nargs="+", action="extend", default=None, metavar="FOLDER",
                   help="log folders to serve (train -f; default: logs); repeat or list several")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1; others need --token)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"port (default {DEFAULT_PORT}; 0: any free port)")
    p.add_argument("--token", default=None, help=f"secret every request must carry (or set {TOKEN_ENV_VAR})")
    p.add_argument("-v", "--verbose", action="store_true", help="log every request")
    return p


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv`` and serve until Ctrl-C."""
    args = build_parser().parse_args(argv)
    options = DashboardOptions(args.folders or ["logs"], args.host, args.port, args.token, quiet=not args.verbose)
    return serve(options)


if __name__ == "__main__":
    run("python -m sbagents.dashboard", main)
