"""``python -m sbagents.serve``: serve an exported policy over stdin/stdout (one JSON line per decision) or HTTP.

Usage::

    python -m sbagents.serve --model policy.onnx [--meta policy.json] [--csv decisions.csv]
    python -m sbagents.serve --algo ddpg --env SmartHome-v0 [-f logs] [--exp-id K] [--int8]   # a run's export
    python -m sbagents.serve --model policy.onnx --http 127.0.0.1:8000                       # POST one observation
    python -m sbagents.serve --model policy.onnx --http 0.0.0.0:8000 [--allow-any-host]      # from other machines

With ``--model`` it needs only numpy and onnxruntime (no torch, SB3 or gymnasium): an edge device installs those
two and copies the export folder. The protocols are in :mod:`sbagents.deploy.serving` and
:mod:`sbagents.deploy.http_serving`: a line or request that is not one observation gets ``{"error": ...}`` and
serving goes on. Exit status: 0 at end of input (stdin) or on Ctrl-C / SIGTERM (HTTP); 2 with one line on stderr
when the model or sidecar is missing or invalid, or the address cannot be bound.
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
    p.add_argument("--http", default=None, metavar="HOST:PORT",
                   help="serve over HTTP instead of stdin/stdout: POST one observation, get one action (PORT alone: "
                        "127.0.0.1; port 0: a free one). Loopback unless you name another host: there is no "
                        "authentication. Requests must name the bound address in their Host header")
    p.add_argument("--allow-any-host", action="store_true",
                   help="with --http: answer whatever Host header a request carries (behind a proxy or a port "
                        "forward that changes it); by default a Host that is not the bound address gets 421, which "
                        "keeps web pages reached by DNS rebinding out")
    run_flags = p.add_argument_group("or a run's export (<run dir>/export, made by python -m sbagents.export)")
    add_run_arguments(run_flags, required=False, load_best=False, trust=False)
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
    if args.allow_any_host and args.http is None:
        raise UsageError("--allow-any-host is for --http HOST:PORT (stdin/stdout has no Host header)")
    try:
        policy = Policy(path, args.meta)
    except (OSError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    if args.http is None:
        serve(policy, sys.stdin.buffer, sys.stdout, args.csv)
        return 0
    return serve_http(policy, args.http, args.csv, args.allow_any_host)


def serve_http(policy: Policy, address: str, csv_path: str | None, allow_any_host: bool = False) -> int:
    """Serve ``policy`` on ``address`` until Ctrl-C or SIGTERM; one line on stderr when it starts and stops."""
    from sbagents.deploy.http_serving import bind, is_loopback, parse_address

    try:
        host, port = parse_address(address)
        server = bind((host, port), policy, csv_path, allow_any_host=allow_any_host)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    bound_host, bound_port = str(server.server_address[0]), int(server.server_address[1])
    shown = f"[{bound_host}]" if ":" in bound_host else bound_host
    note = "" if is_loopback(host) else " (reachable from other machines, no authentication)"
    note += "; any Host header accepted" if allow_any_host else ""
    print(f"serving {policy.path.name} on http://{shown}:{bound_port}/{note}: POST one observation, GET / "
          "describes the policy; Ctrl-C stops", file=sys.stderr, flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
    print(f"stopped: {server.served} decisions, {server.errors} malformed requests, {server.refused} refused "
          "(route, method, size, Host or Content-Type)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    run("python -m sbagents.serve", main)
