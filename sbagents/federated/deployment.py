"""A real Flower deployment on this machine: a SuperLink (the server) and one SuperNode per home, each its own
process, talking over HTTP on localhost; the run is submitted with ``flwr run``.

Server: ``python -m sbagents.federated --deploy`` (:func:`run_deployment`): starts ``flower-superlink``, submits
the app (a generated Flower app dir whose components are :data:`sbagents.federated.apps.server_app` /
``client_app`` and whose run config is the settings), shows each round as ``rounds.csv`` grows, and stops the
SuperLink when the run ends. Homes: ``python -m sbagents.federated.home --home I`` (:mod:`sbagents.federated.home`).
Flower's logs go to ``superlink.log`` and ``flwr-run.log`` in the run dir.
"""

from __future__ import annotations

import contextlib
import csv
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from sbagents.errors import UsageError
from sbagents.federated.settings import FederatedSettings

#: How long the SuperLink may take to listen.
START_TIMEOUT = 60.0
CONNECTION = "sbagents"


def flower_path() -> str:
    """``PATH`` with this Python's scripts first: Flower's processes start the others by name (the SuperLink
    starts ``flower-superexec``, a SuperNode ``flwr-clientapp``), also from a venv that is not activated."""
    return os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")])


def flower_env(**extra: str) -> dict[str, str]:
    """The environment of Flower's processes: :func:`flower_path`, no telemetry, and ``extra``."""
    return {**os.environ, "PATH": flower_path(), "FLWR_TELEMETRY_ENABLED": "0", **extra}


def flower_command(name: str) -> str:
    """The path of a Flower console script (``flower-superlink``, ``flwr``...) of this Python's environment."""
    found = shutil.which(name, path=flower_path())
    if found is None:
        raise UsageError(f"{name} not found next to {sys.executable}: pip install 'sbagents[federated]'")
    return found


def port_open(host: str, port: int, timeout: float = 0.5) -> bool:
    """Whether something accepts TCP connections on ``host:port``."""
    with contextlib.suppress(OSError), socket.create_connection((host, port), timeout=timeout):
        return True
    return False


def check_port_free(host: str, port: int, flag: str) -> None:
    """:class:`UsageError` (one line) when ``host:port`` cannot be bound (in use, or not ours)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        try:
            sock.bind((host, port))
        except OSError as exc:
            raise UsageError(f"{flag} {port}: cannot listen on {host}:{port} ({exc.strerror}); pick another port") \
                from None


def toml_value(value: Any) -> str:
    """A TOML literal of a run-config value (str, bool, int, float)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    return json.dumps(str(value))  # a TOML basic string is a JSON string


def write_app(folder: Path, run_config: dict[str, Any]) -> Path:
    """A Flower app dir (``pyproject.toml`` only: the components are imported from the installed sbagents)."""
    folder.mkdir(parents=True, exist_ok=True)
    config = "\n".join(f"{k} = {toml_value(v)}" for k, v in run_config.items())
    (folder / "pyproject.toml").write_text(f"""[build-system]
requires = ["hatchling"]
build-backend = "hatchling.build"

[project]
name = "sbagents-federated-homes"
version = "1.0.0"
description = "sbagents: one SmartHome policy across homes"
license = "MIT"
dependencies = []

[tool.flwr.app]
publisher = "sbagents"

[tool.flwr.app.components]
serverapp = "sbagents.federated.apps:server_app"
clientapp = "sbagents.federated.apps:client_app"

[tool.flwr.app.config]
{config}
""")
    return folder


def write_connection(flwr_home: Path, port: int) -> None:
    """The ``flwr`` CLI's SuperLink connection (``FLWR_HOME/config.toml``) to the local SuperLink."""
    flwr_home.mkdir(parents=True, exist_ok=True)
    (flwr_home / "config.toml").write_text(f"""[superlink]
default = "{CONNECTION}"

[superlink.{CONNECTION}]
address = "127.0.0.1:{port}"
insecure = true
""")


@contextlib.contextmanager
def running(cmd: list[str], log: Path, env: dict[str, str]) -> Iterator[subprocess.Popen[bytes]]:
    """A child process with its output in ``log``, terminated (then killed) when the block ends."""
    with log.open("ab") as out:
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        try:
            yield proc
        finally:
            stop(proc)


def stop(proc: subprocess.Popen[bytes], grace: float = 10.0) -> None:
    """Terminate ``proc`` (SIGTERM, then SIGKILL after ``grace`` seconds)."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(grace)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def run_deployment(settings: FederatedSettings, run_dir: Path, port: int, report: Any = print) -> None:
    """Start a SuperLink on ``127.0.0.1:port``, run the federation on the homes that connect, stop the SuperLink.
    The caller checks the port first (:func:`check_port_free`, before it makes the run dir).

    :raises UsageError: the SuperLink does not start, or the run fails (logs named).
    """
    from sbagents.federated.server import ROUNDS_FILE

    with tempfile.TemporaryDirectory(prefix="sbagents-flwr-") as tmp:
        flwr_home = Path(tmp) / "flwr"
        write_connection(flwr_home, port)
        app = write_app(Path(tmp) / "app", {**settings.to_run_config(), "run-dir": str(run_dir.resolve())})
        env = flower_env(FLWR_HOME=str(flwr_home))
        superlink = [flower_command("flower-superlink"), "--insecure", "--host", "127.0.0.1", "--port", str(port)]
        with running(superlink, run_dir / "superlink.log", env) as link:
            wait_for_port(port, link, run_dir / "superlink.log")
            report(f"SuperLink on 127.0.0.1:{port}; waiting for {settings.homes} homes, each started with:")
            report(f"  python -m sbagents.federated.home --home I --superlink 127.0.0.1:{port}   "
                   f"(I = 0..{settings.homes - 1})")
            flwr_run = [flower_command("flwr"), "run", str(app), CONNECTION, "--stream"]
            with running(flwr_run, run_dir / "flwr-run.log", env) as submitted:
                follow_rounds(run_dir / ROUNDS_FILE, submitted, settings.rounds, report)
                if submitted.returncode != 0:
                    raise UsageError(f"the Flower run failed (exit {submitted.returncode}); see "
                                     f"{run_dir / 'flwr-run.log'} and {run_dir / 'superlink.log'}")


def wait_for_port(port: int, proc: subprocess.Popen[bytes], log: Path) -> None:
    """Wait until the SuperLink listens; :class:`UsageError` if it exits or takes longer than START_TIMEOUT."""
    deadline = time.monotonic() + START_TIMEOUT
    while not port_open("127.0.0.1", port):
        if proc.poll() is not None or time.monotonic() > deadline:
            raise UsageError(f"the SuperLink did not start on 127.0.0.1:{port}; see {log}")
        time.sleep(0.2)


def follow_rounds(rounds_csv: Path, proc: subprocess.Popen[bytes], rounds: int, report: Any) -> None:
    """Report each new row of ``rounds.csv`` (written by the ServerApp's process) until ``proc`` ends."""
    from sbagents.federated.server import round_line

    shown = 0
    while True:
        done = proc.poll() is not None
        if rounds_csv.exists():
            with rounds_csv.open(newline="") as f:
                rows = list(csv.DictReader(f))
            for row in rows[shown:]:
                report(round_line({k: _number(v) for k, v in row.items()}, rounds))
            shown = max(shown, len(rows))
        if done:
            return
        time.sleep(0.5)


def _number(text: str) -> Any:
    if text == "":
        return None
    with contextlib.suppress(ValueError):
        return int(text)
    with contextlib.suppress(ValueError):
        return float(text)
    return text
