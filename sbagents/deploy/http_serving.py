"""The decision loop over HTTP: POST one JSON observation, get one JSON action (a local hub's policy server).

Same JSON shapes, error replies and CSV log as the stdin/stdout loop of :mod:`sbagents.deploy.serving`; like it,
this module needs only numpy and onnxruntime (the server is the standard library's ``http.server``).

Routes:

- ``POST /`` (or ``/act``): the body is one observation (a JSON list, or an object keyed by ``obs_names``).
  200 with the action (a JSON list of floats, or an int); 400 with ``{"error": reason}`` for a malformed body
  (the same reasons as the line protocol); 411 without ``Content-Length``; 413 for a body over
  :data:`MAX_BODY` bytes.
- ``GET /`` (or ``/policy``): 200 with ``{"obs_names", "action_names", "discrete_action"}``.
- Anything else: 404 (unknown path) or 405 (other methods), with ``{"error": reason}``.

Connections are kept alive (HTTP/1.1); each client connection has its own thread, and decisions are made and
logged one at a time.
"""

from __future__ import annotations

import errno
import ipaddress
import json
import socket
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from sbagents.deploy.serving import DecisionLog, Policy, decide

#: Largest request body accepted (bytes); an observation is a few hundred.
MAX_BODY = 64 * 1024
ACT_PATHS = ("/", "/act")
INFO_PATHS = ("/", "/policy")


class PolicyHTTPServer(ThreadingHTTPServer):
    """A threaded HTTP server around one :class:`~sbagents.deploy.serving.Policy` and its decision log.

    :param address: ``(host, port)``; port 0 takes a free port (read it back from ``server_address``).
    :param csv_path: append every served decision to this CSV (None: no log).
    :raises OSError: the address cannot be bound (``errno.EADDRINUSE`` when the port is in use).
    """

    daemon_threads = True
    allow_reuse_address = False  # a port in use is an error, not something to share

    def __init__(self, address: tuple[str, int], policy: Policy, csv_path: str | Path | None = None) -> None:
        if ":" in address[0]:
            self.address_family = socket.AF_INET6
        self.policy = policy
        self.log: DecisionLog | None = None
        self.lock = threading.Lock()
        self.served = self.errors = 0
        super().__init__(address, _Handler)  # binds (closes itself when that fails)
        self.log = DecisionLog(policy, csv_path)

    def act(self, body: str) -> tuple[bool, str]:
        """Decide on one observation (thread-safe); ``(ok, reply JSON)``."""
        with self.lock:
            assert self.log is not None, "the server is closed"
            ok, reply = decide(self.policy, body, self.log)
            self.served += ok
            self.errors += not ok
        return ok, reply

    def server_close(self) -> None:
        super().server_close()
        if self.log is not None:
            self.log.close()


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    disable_nagle_algorithm = True  # replies are small: send at once (else ~40 ms waits on delayed ACKs)
    server: PolicyHTTPServer

    def do_POST(self) -> None:  # noqa: N802 (http.server's naming)
        length = self.headers.get("Content-Length")
        if length is None or not length.isdigit():
            self._reply(411, _error("Content-Length is required (one JSON observation per request)"), close=True)
            return
        if int(length) > MAX_BODY:
            self._reply(413, _error(f"body of {length} bytes; at most {MAX_BODY}"), close=True)
            return
        raw = self.rfile.read(int(length))  # read before any reply: the connection stays usable
        if self.path not in ACT_PATHS:
            self._reply(404, _error(f"no route {self.path}; POST an observation to / or /act"))
            return
        try:
            body = raw.decode("utf-8")
        except UnicodeDecodeError:
            self._reply(400, _error("body is not UTF-8 text"))
            return
        ok, reply = self.server.act(body)
        self._reply(200 if ok else 400, reply)

    def do_GET(self) -> None:  # noqa: N802
        if self.path not in INFO_PATHS:
            self._reply(404, _error(f"no route {self.path}; GET / describes the policy, POST / decides"))
            return
        policy = self.server.policy
        self._reply(200, json.dumps({"obs_names": list(policy.obs_names), "action_names": list(policy.action_names),
                                     "discrete_action": policy.discrete_action}))

    def _not_allowed(self) -> None:
        self._reply(405, _error(f"{self.command} is not served; POST an observation, GET the policy"), close=True)

    do_PUT = do_DELETE = do_PATCH = _not_allowed  # noqa: N815

    def _reply(self, status: int, body: str, close: bool = False) -> None:
        data = (body + "\n").encode()
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(data)))
        if close:
            self.send_header("Connection", "close")
            self.close_connection = True
        self.end_headers()
        self.wfile.write(data)

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - one line per request is noise here
        pass


def _error(reason: str) -> str:
    return json.dumps({"error": reason})


def parse_address(text: str) -> tuple[str, int]:
    """``HOST:PORT``, ``[IPv6]:PORT`` or ``PORT`` (loopback) -> ``(host, port)``.

    :raises ValueError: not one of those forms, or a port outside 0-65535.
    """
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = "127.0.0.1", text
    host = host.strip("[]") or "127.0.0.1"
    if not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"--http {text!r}: expected HOST:PORT or PORT with a port in 0-65535 (e.g. 127.0.0.1:8000)")
    return host, int(port)


def is_loopback(host: str) -> bool:
    """Whether ``host`` only listens on this machine (``localhost``, 127.0.0.0/8, ``::1``)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def bind(address: tuple[str, int], policy: Policy, csv_path: str | Path | None = None) -> PolicyHTTPServer:
    """A bound :class:`PolicyHTTPServer` (not yet serving).

    :raises ValueError: the port is in use, or the host cannot be bound here (one readable line).
    """
    try:
        return PolicyHTTPServer(address, policy, csv_path)
    except OSError as exc:
        where = f"{address[0]}:{address[1]}"
        if exc.errno == errno.EADDRINUSE:
            raise ValueError(f"port {address[1]} is in use on {address[0]} (another server?); pick another "
                             "port, or 0 for a free one") from None
        raise ValueError(f"cannot listen on {where}: {exc.strerror or exc}") from None
