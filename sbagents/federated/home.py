"""``python -m sbagents.federated.home --home I``: one home of a real deployment (a Flower SuperNode).

The home trains on its own experience; its model, optimizers and replay buffer stay in its state folder (a
temporary one unless ``--state-dir``), and only parameters go to the server. ``--preferred-temp`` /
``--preferred-light`` set the home's own user (kept at home); without them the home takes user ``I`` of the
server's draw. The home stops by itself when the server has gone.
"""

from __future__ import annotations

import argparse
import contextlib
import subprocess
import tempfile
import time
from pathlib import Path

from sbagents.cli_common import ArgumentParser, run
from sbagents.errors import UsageError

#: Seconds the server may be unreachable before a home that was connected stops.
GONE_AFTER = 10.0
#: The homes' own ports (Flower's ClientAppIo) start here: home I listens on BASE_PORT + I unless --port.
BASE_PORT = 9100


def build_parser() -> ArgumentParser:
    p = ArgumentParser(prog="python -m sbagents.federated.home",
                       description="One home of a federated deployment (a Flower SuperNode).")
    p.add_argument("--home", type=int, required=True, help="this home's number, 0..homes-1")
    p.add_argument("--superlink", default="127.0.0.1:8000", help="the server's address (default 127.0.0.1:8000)")
    p.add_argument("--preferred-temp", type=float, default=None, help="this home's user: preferred temperature (C)")
    p.add_argument("--preferred-light", type=float, default=None, help="this home's user: preferred light (lux)")
    p.add_argument("--state-dir", default=None, help="where the home keeps its model and experience "
                                                     "(default: a temporary folder, removed at exit)")
    p.add_argument("--port", type=int, default=None, help=f"this home's local port (default {BASE_PORT} + home)")
    p.add_argument("--wait", type=float, default=300.0, help="seconds to wait for the server (default 300)")
    return p


def node_config(args: argparse.Namespace, state_dir: Path) -> str:
    """Flower's ``--node-config`` of this home."""
    parts = [f"home={args.home}", f'state-dir="{state_dir}"']
    if args.preferred_temp is not None:
        parts.append(f"preferred-temp={args.preferred_temp}")
    if args.preferred_light is not None:
        parts.append(f"preferred-light={args.preferred_light}")
    return " ".join(parts)


def parse_address(address: str) -> tuple[str, int]:
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise UsageError(f"--superlink {address!r}: expected HOST:PORT, e.g. 127.0.0.1:8000")
    return host, int(port)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from sbagents.federated.deployment import check_port_free, flower_command, flower_env, port_open, stop

    if args.home < 0:
        raise UsageError(f"--home must be >= 0, got {args.home}")
    host, port = parse_address(args.superlink)
    own_port = args.port if args.port is not None else BASE_PORT + args.home
    check_port_free("127.0.0.1", own_port, "--port")
    deadline = time.monotonic() + args.wait
    while not port_open(host, port):
        if time.monotonic() > deadline:
            raise UsageError(f"no server at {args.superlink} after {args.wait:.0f} s (start it with "
                             "python -m sbagents.federated --deploy)")
        time.sleep(0.5)
    with contextlib.ExitStack() as stack:
        if args.state_dir is None:
            state_dir = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix=f"sbagents-home-{args.home}-")))
        else:
            state_dir = Path(args.state_dir).resolve()
            state_dir.mkdir(parents=True, exist_ok=True)
        cmd = [flower_command("flower-supernode"), "--insecure", "--superlink", args.superlink,
               "--port", str(own_port), "--node-config", node_config(args, state_dir)]
        print(f"home {args.home}: connected to {args.superlink}; its model and experience stay in {state_dir}",
              flush=True)
        with (state_dir / "supernode.log").open("ab") as log:
            proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=flower_env(),
                                    start_new_session=True)
            try:
                return watch(proc, host, port, args.home)
            finally:
                stop(proc)
    return 0


def watch(proc: subprocess.Popen[bytes], host: str, port: int, home: int) -> int:
    """Wait while the SuperNode runs; stop it once the server has been unreachable for :data:`GONE_AFTER` s."""
    from sbagents.federated.deployment import port_open

    gone_since: float | None = None
    while proc.poll() is None:
        if port_open(host, port):
            gone_since = None
        elif gone_since is None:
            gone_since = time.monotonic()
        elif time.monotonic() - gone_since > GONE_AFTER:
            print(f"home {home}: the server has gone; stopping", flush=True)
            return 0
        time.sleep(1.0)
    return int(proc.returncode or 0)


if __name__ == "__main__":
    run("python -m sbagents.federated.home", main)
