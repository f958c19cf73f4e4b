"""``python -m sbagents.serve``: serve an exported policy over stdin/stdout, one JSON line per decision.

Usage::

    python -m sbagents.serve --model policy.onnx [--meta policy.json] [--csv decisions.csv]
    python -m sbagents.serve --algo ddpg --env SmartHome-v0 [-f logs] [--exp-id K] [--int8]   # a run's export

With ``--model`` it needs only numpy and onnxruntime (no torch, SB3 or gymnasium): an edge device installs those
two and copies the export folder. The protocol is in :mod:`sbagents.deploy.serving`. Exit status: 0 at end of input;
2 with one line on stderr when the model or sidecar is missing or invalid.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from sbagents.cli_common import ArgumentParser, add_run_arguments, run, run_ref
from sbagents.deploy.serving import Policy, serve
from sbagents.errors import UsageError


def build_parser() -> ArgumentParser:
    """The ``serve`` argument parser."""
    p = ArgumentParser(prog="python -m sbagents.serve",
                       description="Serve an exported ONNX policy over stdin/stdout (JSON lines).")
    p.add_argument("--model", default=None, help="policy.onnx or policy.int8.onnx (or pick a run's export below)")
    p.add_argument("--meta", default=None, help="sidecar JSON (default: policy.json next to the model)")
    p.add_argument("--csv", default=None, help="append every decision to this CSV file")
    run_flags = p.add_argument_group("or a run's export (<run dir>/export, made by python -m sbagents.export)")
    add_run_arguments(run_flags, required=False, load_best=False)
    run_flags.add_argument("--int8", action="store_true", help="serve policy.int8.onnx")
    return p


def model_file(model: str | None, algo: str | None, run_dir: Path | None, int8: bool) -> Path:
    """The ONNX file to serve: ``--model``, or the export of the run ``--algo/--env`` pick."""
    if model is not None:
        if algo is not None:
            raise UsageError("give --model or --algo/--env, not both")
        return Path(model)
    if run_dir is None:
        raise UsageError("the following arguments are required: --model (or --algo and --env of an exported run)")
    path = run_dir / "export" / ("policy.int8.onnx" if int8 else "policy.onnx")
    if not path.exists():
        raise UsageError(f"{path} does not exist; export the run first (python -m sbagents.export --algo {algo} "
                         f"--env ...{' --int8' if int8 else ''})")
    return path


def main(argv: Sequence[str] | None = None) -> int:
    """CLI entry point; returns the exit status."""
    args = build_parser().parse_args(argv)
    run_dir = run_ref(args).run_dir() if args.model is None and args.algo is not None else None
    path = model_file(args.model, args.algo, run_dir, args.int8)
    try:
        policy = Policy(path, args.meta)
    except (OSError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    serve(policy, sys.stdin, sys.stdout, args.csv)
    return 0


if __name__ == "__main__":
    run("python -m sbagents.serve", main)
