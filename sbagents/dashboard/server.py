"""Serving the dashboard: checks the options (folders exist, a token for any address but loopback, the port is
free) before anything starts, then runs Werkzeug's threaded WSGI server until Ctrl-C.

Werkzeug's server (Flask's own) is enough for a few operators on a read-only app; behind a reverse proxy with
TLS, mount :func:`sbagents.dashboard.app.create_app` in any WSGI server instead.

The token is in no line this module prints: the start line says where to add it, and every line of the server's
log (``-v`` request lines, errors that quote a bad request line) has its ``token=`` query values replaced by
``***`` (:func:`redact_token`).
"""

from __future__ import annotations

import errno
import ipaddress
import os
import re
import socket
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import unquote_plus

from sbagents.errors import UsageError

#: Environment variable read when ``--token`` is not given (keeps the token out of ``ps`` listings).
TOKEN_ENV_VAR = "SBAGENTS_DASHBOARD_TOKEN"
DEFAULT_PORT = 8050
#: A ``name=value`` pair of a query string (the value runs to the next ``&`` or white space).
_QUERY_PAIR = re.compile(r"([?&;])([^=&?;\s]*)=([^&\s]*)")


def redact_token(text: str) -> str:
    """``text`` with the value of every ``token=`` query pair replaced by ``***`` (the name compared after
    percent-decoding, as the app reads it: ``?%74oken=`` is a token too)."""
    def hide(match: re.Match[str]) -> str:
        return f"{match[1]}{match[2]}=***" if unquote_plus(match[2]).strip() == "token" else match[0]

    return _QUERY_PAIR.sub(hide, text)


@dataclass
class DashboardOptions:
    """What ``python -m sbagents.dashboard`` serves and where.

    :param folders: log folders (``train -f``) to serve, read-only.
    :param host: address to bind; anything but a loopback address needs ``token``.
    :param port: TCP port (0: any free port, printed at start).
    :param token: a secret every request must carry (``?token=`` once, then a cookie; or ``Authorization: Bearer``).
    :param quiet: no per-request log lines.
    """

    folders: Sequence[str] = field(default_factory=lambda: ["logs"])
    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    token: str | None = None
    quiet: bool = True


def is_loopback(host: str) -> bool:
    """Whether ``host`` is a loopback name or address (``localhost``, ``127.0.0.0/8``, ``::1``)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def serve(options: DashboardOptions) -> int:
    """Serve the dashboard until interrupted; return 0.

    :raises UsageError: a folder does not exist, a non-loopback ``host`` without a token, a bad or busy port.
    """
    try:
        import plotly  # noqa: F401  (its bundled plotly.js draws the charts)
        from werkzeug.serving import WSGIRequestHandler, make_server

        from sbagents.dashboard.app import create_app
    except ImportError as exc:
        raise UsageError(f"the dashboard needs Flask and plotly ({exc.name} is missing): "
                         "pip install 'sbagents[dashboard]'") from None
    from sbagents.dashboard.folders import ServedFolders

    folders = ServedFolders.from_paths(options.folders)
    token = options.token or os.environ.get(TOKEN_ENV_VAR) or None
    if not is_loopback(options.host) and token is None:
        raise UsageError(f"--host {options.host} is reachable from other machines: give --token SECRET "
                         f"(or set {TOKEN_ENV_VAR}); without one, bind 127.0.0.1")
    if token is not None and len(token) < 8:
        raise UsageError("--token must be at least 8 characters")
    if not 0 <= options.port <= 65535:
        raise UsageError(f"--port must be 0-65535, got {options.port}")
    app = create_app(folders, token=token, check_host=token is None)

    class Handler(WSGIRequestHandler):
        def log_request(self, code: int | str = "-", size: int | str = "-") -> None:
            if not options.quiet:
                super().log_request(code, size)

        def log(self, type: str, message: str, *args: Any) -> None:  # every line of the server's log
            super().log(type, "%s", redact_token(message % args if args else message))

    try:  # our own socket: Werkzeug prints a paragraph and exits 1 when the port is taken
        family = socket.AF_INET6 if ":" in options.host else socket.AF_INET
        listener = socket.create_server((options.host.strip("[]"), options.port), family=family)
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise UsageError(f"port {options.port} on {options.host} is in use (another dashboard?); "
                             "pick another with --port") from None
        raise UsageError(f"cannot listen on {options.host}:{options.port}: {exc.strerror or exc}") from None
    server = make_server(options.host, listener.getsockname()[1], app, threaded=True, request_handler=Handler,
                         fd=listener.fileno())
    host = f"[{options.host}]" if ":" in options.host else options.host
    url = f"http://{host}:{server.port}/"  # never with the token: this line ends up in logs
    print(f"dashboard: {url}  serving {', '.join(str(r) for r in folders.roots)} read-only (Ctrl-C stops)", flush=True)
    if token:
        print("dashboard: open it with ?token=<your token> once; the browser then keeps a cookie", flush=True)
    try:
        server.serve_forever()  # Werkzeug's returns on Ctrl-C (and SIGTERM, which the CLI turns into Ctrl-C)
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
        listener.close()
    print("dashboard: stopped", flush=True)
    return 0
