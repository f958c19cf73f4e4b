"""The decision loop over HTTP: POST one JSON observation, get one JSON action (a local hub's policy server).

Same JSON shapes, error replies and CSV log as the stdin/stdout loop of :mod:`sbagents.deploy.serving`; like it,
this module needs only numpy and onnxruntime (the server is the standard library's ``http.server``).

Routes:

- ``POST /`` (or ``/act``) with ``Content-Type: application/json``: the body is one observation (a JSON list, or an
  object keyed by ``obs_names``). 200 with the action (a JSON list of floats, or an int); 400 with
  ``{"error": reason}`` for a body that is not one observation (the same reasons as the line protocol).
- ``GET /`` (or ``/policy``): 200 with ``{"obs_names", "action_names", "discrete_action"}``.

Every other answer is an error status with ``{"error": reason}``: 400 (also a body that ends before its
``Content-Length``, and an HTTP version other than 1.x), 404 (unknown path), 405 (any other method, known or not),
408 (a request that did not arrive in full within :data:`REQUEST_TIMEOUT`, or stopped arriving for
:data:`CONNECTION_TIMEOUT`), 411 (no ``Content-Length``; chunked bodies are not taken), 413 (a body over
:data:`MAX_BODY` bytes, or over the policy's larger limit), 415 (a POST that is not ``application/json``: a web page
cannot send one without the browser asking first, which this server never allows), 421 (a ``Host`` header that is
not this server's address: see :func:`host_allowed`; a web page that reaches the server by DNS rebinding carries its
own host name), 429 (a connection beyond :data:`MAX_CONNECTIONS` open at once, with ``Retry-After``), and the
standard library's 400/414/431 for requests it cannot parse. No answer is a 5xx. A problem with the request never
closes the connection without a reply.

Connections are kept alive (HTTP/1.1); each client connection has its own thread. Each request, from the moment the
server starts waiting for it (the connection accepted, or the previous reply sent) to the last byte of its body, must
arrive within :data:`REQUEST_TIMEOUT` seconds in all, whatever the pace of its bytes: a connection that has not
delivered a whole request by then is closed (after a 408 when part of one had come; silently when it was idle, so a
kept-alive connection is closed after that long without a request). A client that trickles bytes therefore holds one
of the :data:`MAX_CONNECTIONS` slots for at most that long. Decisions are made and logged one at a time.
"""

from __future__ import annotations

import errno
import ipaddress
import json
import math
import socket
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from sbagents.deploy.serving import MAX_REQUEST_BYTES, DecisionLog, Policy, decide, error_reply

#: Largest request body accepted (bytes) for a policy of up to 2,048 observation values; an observation is a few
#: hundred. A larger policy's limit is its ``Policy.max_request_bytes`` (32 bytes a value).
MAX_BODY = MAX_REQUEST_BYTES
#: A body over :data:`MAX_BODY` is read past (up to this many bytes) before the 413, so the client gets the reply
#: rather than a connection reset; a larger one is answered and the connection closed at once.
MAX_DRAIN = 1024 * 1024
#: Seconds a request may take to arrive in full (request line, headers and body), counted from when the server starts
#: waiting for it: the connection accepted or the previous reply sent. A connection that has not delivered a whole
#: request by then is closed (after a 408 if part of one came), so a client sending a byte now and then holds a
#: connection slot for at most this long; a kept-alive connection idle for this long is closed too.
REQUEST_TIMEOUT = 10.0
#: Seconds a connection may stay silent within that deadline (no byte of the request) before it is closed, and the
#: longest a reply may wait for the client to take it.
CONNECTION_TIMEOUT = 15.0
#: Connections the kernel queues before the server accepts them (http.server's default is 5).
REQUEST_QUEUE_SIZE = 128
#: Connections served at once (a thread each; one without a whole request is closed after :data:`REQUEST_TIMEOUT`);
#: one more is answered 429 with ``Retry-After`` and closed, so a flood of connections cannot exhaust the server's
#: threads.
MAX_CONNECTIONS = 64
#: Longest request line (http.server's limit: a longer one is answered 414).
MAX_REQUEST_LINE = 65536
ACT_PATHS = ("/", "/act")
INFO_PATHS = ("/", "/policy")
ALLOW_ANY_HOST_FLAG = "--allow-any-host"


class PolicyHTTPServer(ThreadingHTTPServer):
    """A threaded HTTP server around one :class:`~sbagents.deploy.serving.Policy` and its decision log.

    :param address: ``(host, port)``; port 0 takes a free port (read it back from ``server_address``).
    :param csv_path: append every served decision to this CSV (None: no log).
    :param allow_any_host: answer requests whatever their ``Host`` header (by default only this server's address:
        :func:`host_allowed`).
    :param connection_timeout: seconds of silence after which a client connection is closed, and the longest a
        reply waits for the client to take it (default :attr:`connection_timeout`).
    :param max_connections: connections served at once (default :data:`MAX_CONNECTIONS`); another is answered 429.
    :param request_timeout: seconds each request may take to arrive in full, from when the server starts waiting for
        it (default :attr:`request_timeout`, :data:`REQUEST_TIMEOUT`); a connection that has not delivered one by
        then is closed.
    :raises ValueError: a timeout that is not a positive number of seconds.
    :raises OSError: the address cannot be bound (``errno.EADDRINUSE`` when the port is in use) or the CSV log
        cannot be opened.
    """

    daemon_threads = True
    allow_reuse_address = False  # a port in use is an error, not something to share
    request_queue_size = REQUEST_QUEUE_SIZE
    connection_timeout: float = CONNECTION_TIMEOUT
    request_timeout: float = REQUEST_TIMEOUT

    def __init__(self, address: tuple[str, int], policy: Policy, csv_path: str | Path | None = None, *,
                 allow_any_host: bool = False, connection_timeout: float | None = None,
                 max_connections: int = MAX_CONNECTIONS, request_timeout: float | None = None) -> None:
        for name, value in (("connection_timeout", connection_timeout), ("request_timeout", request_timeout)):
            if value is not None and (isinstance(value, bool) or not isinstance(value, int | float)
                                      or not (math.isfinite(value) and value > 0)):
                raise ValueError(f"{name} must be a positive number of seconds, got {value!r}")
        if ":" in address[0]:
            self.address_family = socket.AF_INET6
        self.policy = policy
        self.log: DecisionLog | None = None
        self.lock = threading.Lock()
        self.served = self.errors = self.refused = 0
        self.max_connections = max_connections
        self.open_connections = 0
        self._connections_lock = threading.Lock()
        self.host_name = address[0]  # as the user named it: what a Host header must say
        self.allow_any_host = allow_any_host
        if connection_timeout is not None:
            self.connection_timeout = float(connection_timeout)
        if request_timeout is not None:
            self.request_timeout = float(request_timeout)
        super().__init__(address, _Handler)  # binds (closes itself when that fails)
        try:
            self.log = DecisionLog(policy, csv_path)
        except OSError:
            super().server_close()
            raise

    @property
    def port(self) -> int:
        """The bound port."""
        return int(self.server_address[1])

    def act(self, body: str | bytes) -> tuple[bool, str]:
        """Decide on one observation (thread-safe); ``(ok, reply JSON)``."""
        with self.lock:
            assert self.log is not None, "the server is closed"
            ok, reply = decide(self.policy, body, self.log)
            self.served += ok
            self.errors += not ok
        return ok, reply

    def count_refused(self) -> None:
        """Count one request refused before it reached the policy (route, method, size, Host, Content-Type)."""
        with self.lock:
            self.refused += 1

    def host_ok(self, header: str | None) -> bool:
        """Whether a request with this ``Host`` header is answered."""
        return self.allow_any_host or host_allowed(header, self.host_name, self.port)

    def process_request(self, request: Any, client_address: Any) -> None:
        """Serve the connection in a thread of its own, or answer 429 at once when :attr:`max_connections` are
        open."""
        with self._connections_lock:
            full = self.open_connections >= self.max_connections
            if not full:
                self.open_connections += 1
        if not full:
            try:
                super().process_request(request, client_address)
            except BaseException:  # no thread started: the connection is not open
                with self._connections_lock:
                    self.open_connections -= 1
                raise
            return
        self.count_refused()
        body = json.dumps({"error": f"{self.max_connections} connections are open; retry in a second"}).encode()
        head = (f"HTTP/1.1 429 Too Many Requests\r\nContent-Type: application/json\r\nContent-Length: {len(body)}"
                "\r\nRetry-After: 1\r\nConnection: close\r\n\r\n").encode()
        try:
            request.settimeout(1.0)  # the accept loop never waits on a slow client
            request.sendall(head + body)
        except OSError:
            pass
        self.shutdown_request(request)

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            with self._connections_lock:
                self.open_connections -= 1

    def handle_error(self, request: Any, client_address: Any) -> None:
        """A client that went away is not worth a line; anything else is one line on stderr (no traceback)."""
        exc = sys.exc_info()[1]
        if isinstance(exc, OSError):
            return
        print(f"error while serving {client_address[0]}: {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)

    def server_close(self) -> None:
        super().server_close()
        if self.log is not None:
            self.log.close()


class RequestTimeout(OSError):
    """A request that did not arrive in time (its deadline passed, or the client fell silent); the message says
    which."""


class RequestReader:
    """A client connection's input, buffered like ``socket.makefile("rb")``, under a deadline per request.

    :meth:`start` opens a request's deadline; from then on every read from the socket waits at most until that
    deadline, and at most ``silence`` seconds for its next byte, else raises :class:`RequestTimeout`. So the request
    line, headers and body together take at most the deadline, however slowly their bytes come.

    :param sock: the connected socket (its timeout is set before every read).
    :param silence: seconds a read waits for a byte.
    """

    #: bytes asked of the socket at once
    CHUNK = 65536

    def __init__(self, sock: socket.socket, silence: float) -> None:
        self._sock = sock
        self._silence = silence
        self._buffer = bytearray()
        self._deadline = math.inf
        self._timeout = math.inf
        #: bytes of the current request received so far (counting bytes a previous read took ahead)
        self.received = 0
        self.closed = False

    def start(self, timeout: float) -> None:
        """Start the next request: it must be read in full within ``timeout`` seconds from now."""
        self._timeout = timeout
        self._deadline = time.monotonic() + timeout
        self.received = len(self._buffer)

    def _fill(self) -> bool:
        """Read what the socket has (waiting within the limits); False at the end of the stream."""
        left = self._deadline - time.monotonic()
        if left <= 0:
            raise RequestTimeout(f"the request did not arrive in full within {self._timeout:g} s; send it at once")
        wait = min(left, self._silence)
        self._sock.settimeout(wait)
        try:
            chunk = self._sock.recv(self.CHUNK)
        except TimeoutError:
            if wait < left:
                raise RequestTimeout(f"the request stopped arriving ({self._silence:g} s without a byte)") from None
            raise RequestTimeout(f"the request did not arrive in full within {self._timeout:g} s; send it at "
                                 "once") from None
        self.received += len(chunk)
        self._buffer += chunk
        return bool(chunk)

    def _take(self, size: int) -> bytes:
        data = bytes(self._buffer[:size])
        del self._buffer[:size]
        return data

    def readline(self, limit: int = -1) -> bytes:
        """One line with its ``\\n`` (at most ``limit`` bytes; less at the end of the stream)."""
        scanned = 0
        while True:
            end = self._buffer.find(b"\n", scanned)
            if end >= 0 and (limit < 0 or end < limit):
                return self._take(end + 1)
            if 0 <= limit <= len(self._buffer):
                return self._take(limit)
            scanned = len(self._buffer)
            if not self._fill():
                return self._take(len(self._buffer))

    def read(self, size: int = -1) -> bytes:
        """``size`` bytes (all until the end of the stream when negative; less when it ends first)."""
        while (size < 0 or len(self._buffer) < size) and self._fill():
            pass
        return self._take(len(self._buffer) if size < 0 else size)

    def close(self) -> None:
        self.closed = True
        self._buffer.clear()


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    default_request_version = "HTTP/1.0"  # a garbled request line still gets a status line (not a bare HTTP/0.9 body)
    disable_nagle_algorithm = True  # replies are small: send at once (else ~40 ms waits on delayed ACKs)
    server: PolicyHTTPServer
    rfile: RequestReader  # type: ignore[assignment]  # what http.server reads (readline, read) it has
    raw_requestline: bytes

    def setup(self) -> None:
        super().setup()
        self.rfile.close()  # the plain makefile("rb"): replaced by one with the request deadline
        self.rfile = RequestReader(self.connection, self.server.connection_timeout)

    def handle_one_request(self) -> None:
        """One request under its deadline (:attr:`PolicyHTTPServer.request_timeout` from now): the connection is
        closed when it is not in by then, after a 408 when part of it came."""
        self.rfile.start(self.server.request_timeout)
        self.requestline, self.request_version, self.command = "", self.default_request_version, ""
        try:
            super().handle_one_request()
        except RequestTimeout as exc:
            self.close_connection = True
            if self.rfile.received:  # an idle connection is closed without a word (a client reconnects)
                self._refuse(408, str(exc), close=True)

    def parse_request(self) -> bool:
        """The standard library's, after skipping empty lines before the request line (RFC 9112 section 2.2; it would
        close the connection without a reply)."""
        while not str(self.raw_requestline, "iso-8859-1").split():
            if not self.raw_requestline.endswith(b"\n"):  # the stream ended: nobody to answer
                self.close_connection = True
                return False
            self.raw_requestline = self.rfile.readline(MAX_REQUEST_LINE + 1)
            if len(self.raw_requestline) > MAX_REQUEST_LINE:
                self.send_error(414)
                return False
        return super().parse_request()

    def do_POST(self) -> None:  # noqa: N802 (http.server's naming)
        body = self._read_body(required=True)
        if body is None or not self._host_checked():
            return
        if self.path not in ACT_PATHS:
            self._refuse(404, f"no route {self.path}; POST an observation to / or /act")
        elif self.headers.get_content_type() != "application/json":  # a missing header reads as text/plain
            given = self.headers.get("Content-Type")
            self._refuse(415, f"Content-Type {_shown([given] if given is not None else [])}: POST the observation "
                              "as application/json")
        else:
            ok, reply = self.server.act(body)
            self._reply(200 if ok else 400, reply)

    def do_GET(self) -> None:  # noqa: N802
        if self._read_body(required=False) is None or not self._host_checked():
            return
        if self.path not in INFO_PATHS:
            self._refuse(404, f"no route {self.path}; GET / describes the policy, POST / decides")
            return
        policy = self.server.policy
        self._reply(200, json.dumps({"obs_names": list(policy.obs_names), "action_names": list(policy.action_names),
                                     "discrete_action": policy.discrete_action}))

    def _not_allowed(self) -> None:
        self._refuse(405, f"{_clipped(self.command)} is not served; POST an observation, GET the policy", close=True)

    do_PUT = do_DELETE = do_PATCH = do_OPTIONS = do_HEAD = _not_allowed  # noqa: N815

    def send_error(self, code: int, message: str | None = None, explain: str | None = None) -> None:
        """The standard library's parse errors (400, 414, 431), as ``{"error": ...}`` like every other; what it
        answers with a 5xx is the client's doing, so it gets a 4xx: an unknown method 405 (as the other methods),
        an HTTP version this server does not speak 400."""
        if code == 501:
            self._not_allowed()
            return
        if code == 505:
            code, explain = 400, "send HTTP/1.1 (or HTTP/1.0)"
        reason = message or self.responses.get(code, ("error", ""))[0]
        self._refuse(code, f"{reason}" + (f": {explain}" if explain else ""), close=True)

    def _read_body(self, required: bool) -> bytes | None:
        """The request body (``b""`` when there is none and none is ``required``); None when it was answered
        already (no or a bad ``Content-Length``, too large, stopped arriving) or the client went away."""
        if "Transfer-Encoding" in self.headers:
            self._refuse(411, "chunked bodies are not taken; send Content-Length", close=True)
            return None
        lengths = self.headers.get_all("Content-Length") or []
        if not lengths:
            if required:
                self._refuse(411, "Content-Length is required (one JSON observation per request)", close=True)
                return None
            return b""
        text = lengths[0].strip()
        if len(lengths) > 1 or not (text.isascii() and text.isdigit() and len(text) <= 18):
            self._refuse(400, "Content-Length must be one byte count", close=True)
            return None
        length = int(text)
        limit = self.server.policy.max_request_bytes
        if length > limit:
            self._drain(length)
            self._refuse(413, f"body of {length} bytes; at most {limit}", close=True)
            return None
        body = self.rfile.read(length)  # read before any reply: the connection stays usable
        if len(body) < length:  # the client closed its sending side: it may still read the reply
            self._refuse(400, f"the body ended after {len(body)} of its {length} bytes (Content-Length)", close=True)
            return None
        return body

    def _drain(self, length: int) -> None:
        """Read past up to :data:`MAX_DRAIN` bytes of a body that is refused."""
        left = min(length, MAX_DRAIN)
        while left > 0 and (chunk := self.rfile.read(min(left, 65536))):
            left -= len(chunk)

    def _host_checked(self) -> bool:
        """Whether the ``Host`` header names this server (else the 421 is sent)."""
        hosts = self.headers.get_all("Host") or []
        if len(hosts) <= 1 and self.server.host_ok(hosts[0] if hosts else None):
            return True
        self._refuse(421, f"Host header {_shown(hosts)} does not name this server; expected "
                          f"{expected_hosts(self.server.host_name, self.server.port)} (or start it with "
                          f"{ALLOW_ANY_HOST_FLAG})")
        return False

    def _refuse(self, status: int, reason: str, close: bool = False) -> None:
        self.server.count_refused()
        self._reply(status, error_reply(reason), close)

    def _reply(self, status: int, body: str, close: bool = False) -> None:
        self.connection.settimeout(self.server.connection_timeout)  # the reads left it at their deadline's remainder
        data = (body + "\n").encode()
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(data)))
        if close:
            self.send_header("Connection", "close")
            self.close_connection = True
        self.end_headers()
        if getattr(self, "command", "") != "HEAD":
            self.wfile.write(data)

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - one line per request is noise here
        pass


def _clipped(text: str, limit: int = 40) -> str:
    """``text`` cut to ``limit`` characters (a reply never echoes a whole hostile request)."""
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _shown(hosts: list[str]) -> str:
    if not hosts:
        return "(none)"
    text = ", ".join(hosts)
    return repr(text if len(text) <= 80 else text[:77] + "...")


def parse_address(text: str) -> tuple[str, int]:
    """``HOST:PORT``, ``[IPv6]:PORT`` or ``PORT`` (loopback) -> ``(host, port)``.

    :raises ValueError: not one of those forms, or a port outside 0-65535.
    """
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = "127.0.0.1", text
    host = host.strip("[]") or "127.0.0.1"
    if not (port.isascii() and port.isdigit()) or not 0 <= int(port) <= 65535:
        raise ValueError(f"--http {text!r}: expected HOST:PORT or PORT with a port in 0-65535 (e.g. 127.0.0.1:8000)")
    return host, int(port)


def is_loopback(host: str) -> bool:
    """Whether ``host`` only listens on this machine (``localhost``, 127.0.0.0/8, ``::1``)."""
    if host.lower() == "localhost":
        return True
    ip = _ip(host)
    return ip is not None and ip.is_loopback


def _ip(host: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    try:
        return ipaddress.ip_address(host.strip("[]"))
    except ValueError:
        return None


def _is_wildcard(host: str) -> bool:
    ip = _ip(host)
    return host == "" or (ip is not None and ip.is_unspecified)


def split_host(value: str) -> tuple[str, int | None] | None:
    """A ``Host`` header -> ``(host, port)``: the host lower-case without IPv6 brackets, the port None when not
    given; None when the header is malformed."""
    value = value.strip().lower()
    if value.startswith("["):
        host, bracket, rest = value[1:].partition("]")
        if not bracket or (rest and not rest.startswith(":")) or _ip(host) is None:
            return None
        port = rest[1:]
    else:
        host, _, port = value.partition(":")  # a second ':' (an IPv6 address without brackets) fails the port
    if not host:
        return None
    if not port:
        return host, None
    if not (port.isascii() and port.isdigit() and len(port) <= 5):
        return None
    return host, int(port)


def host_allowed(header: str | None, bound: str, port: int) -> bool:
    """Whether a request whose ``Host`` header is ``header`` is for the server bound to ``bound``:``port``.

    The port must be ``port`` (absent means 80). The host: ``localhost`` or a loopback address when bound to loopback;
    ``localhost`` or any IP address when bound to all addresses (``0.0.0.0``, ``::``: a DNS-rebinding page carries
    a name, not an address); else the host the server was bound to, as named. A missing or malformed header is not
    allowed.
    """
    parsed = split_host(header) if header is not None else None
    if parsed is None:
        return False
    host, given_port = parsed
    if (80 if given_port is None else given_port) != port:
        return False
    bound = bound.strip("[]").lower()
    ip = _ip(host)
    if is_loopback(bound):
        return host == "localhost" or (ip is not None and ip.is_loopback)
    if _is_wildcard(bound):
        return host == "localhost" or ip is not None
    bound_ip = _ip(bound)
    return ip == bound_ip if bound_ip is not None else host == bound.rstrip(".")


def expected_hosts(bound: str, port: int) -> str:
    """The ``Host`` headers :func:`host_allowed` takes for ``bound``:``port``, in words."""
    shown = f"[{bound}]" if ":" in bound else bound
    if is_loopback(bound):
        return f"localhost:{port} or a loopback address such as 127.0.0.1:{port}"
    if _is_wildcard(bound):
        return f"an IP address of this machine with :{port}, or localhost:{port}"
    return f"{shown}:{port}"


def bind(address: tuple[str, int], policy: Policy, csv_path: str | Path | None = None, *,
         allow_any_host: bool = False, connection_timeout: float | None = None,
         max_connections: int = MAX_CONNECTIONS, request_timeout: float | None = None) -> PolicyHTTPServer:
    """A bound :class:`PolicyHTTPServer` (not yet serving); the keywords are the server's.

    :raises ValueError: the port is in use, or the host cannot be bound here (one readable line), or a timeout is not
        a positive number of seconds.
    :raises OSError: the CSV log cannot be opened.
    """
    try:
        return PolicyHTTPServer(address, policy, csv_path, allow_any_host=allow_any_host,
                                connection_timeout=connection_timeout, max_connections=max_connections,
                                request_timeout=request_timeout)
    except OSError as exc:
        if exc.filename is not None:  # the CSV log, not the address
            raise
        where = f"{address[0]}:{address[1]}"
        if exc.errno == errno.EADDRINUSE:
            raise ValueError(f"port {address[1]} is in use on {address[0]} (another server?); pick another "
                             "port, or 0 for a free one") from None
        raise ValueError(f"cannot listen on {where}: {exc.strerror or exc}") from None
