"""The dashboard's Flask app: read-only pages and JSON endpoints over the served log folders.

Pages (HTML shells filled by ``static/dashboard.js``): ``/`` runs, ``/run/<folder>/<run>`` one run,
``/decisions/<folder>/<run>`` its transparency logs, ``/trust/<folder>/<run>`` safety, attacks and fairness,
``/compare?run=<id>&run=<id>`` several runs' curves. JSON under ``/api/``; files under ``/file/<folder>/<path>``.
Every path goes through :class:`~sbagents.dashboard.folders.ServedFolders` (404 outside the folders), every file a
run's readers open through :class:`~sbagents.dashboard.folders.RunFiles`; every file is opened once
(:func:`~sbagents.dashboard.folders.open_regular`) and read or streamed from that open file. A run dir's files cannot
run script in the dashboard's origin: only passive types (:data:`INLINE_TYPES`) are inline, the rest (html, svg,
js, ...) are attachments, all with a sandbox CSP (:data:`FILE_CSP`) and ``nosniff``. A malformed file gives a note
in the JSON, a bad query value a 400 (:mod:`sbagents.dashboard.queryargs`); no route answers 5xx for either.
"""

from __future__ import annotations

import hmac
import math
import os
from typing import Any, BinaryIO

from flask import Flask, Response, abort, jsonify, render_template, request, send_file

from sbagents.dashboard import readers
from sbagents.dashboard.episode_costs import episode_costs
from sbagents.dashboard.folders import RunFiles, ServedFolders, open_regular
from sbagents.dashboard.logindex import LogIndex, Page
from sbagents.dashboard.logregistry import index_in_background, open_log
from sbagents.dashboard.queryargs import int_arg, optional_int, row_filter
from sbagents.dashboard.runs import RunCatalog, is_run_dir, summarize_run

#: Cookie that carries the token after the first request that had it in the URL.
TOKEN_COOKIE = "sbagents_dashboard_token"
#: Most rows one decisions request returns.
MAX_PAGE_ROWS = 1000
LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]", "::1")
#: Content-Security-Policy of the pages: scripts only from the dashboard itself.
PAGE_CSP = ("default-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data: blob:; "
            "media-src 'self'; connect-src 'self'; object-src 'none'; frame-ancestors 'none'")
#: Content-Security-Policy of every file of a run dir: a sandbox (an opaque origin, no script), nothing loaded but
#: the file itself (an image or a video opened on its own).
FILE_CSP = "sandbox; default-src 'none'; img-src 'self'; media-src 'self'; frame-ancestors 'none'"
#: Files of a run dir served inline, with this type: passive formats a browser shows without running anything.
#: Every other file (html, svg, js, xml, ...) is an attachment of type ``application/octet-stream``.
INLINE_TYPES = {
    ".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".gif": "image/gif", ".webp": "image/webp",
    ".mp4": "video/mp4", ".webm": "video/webm", ".csv": "text/csv", ".json": "application/json",
    ".txt": "text/plain", ".log": "text/plain", ".yml": "text/plain", ".yaml": "text/plain",
}


def create_app(folders: ServedFolders, token: str | None = None, check_host: bool = True) -> Flask:
    """The dashboard app serving ``folders`` read-only.

    :param token: when set, every request must carry it (``?token=``, an ``Authorization: Bearer`` header, or the
        cookie set after the first request with ``?token=``); others get 401.
    :param check_host: without a token, answer only requests whose ``Host`` is a loopback name (a web page on
        another site cannot read the logs through DNS rebinding).
    """
    app = Flask(__name__)
    app.url_map.merge_slashes = False  # "/file/0//etc/passwd" is an absolute path: 404, not a redirect
    catalog = RunCatalog(folders)

    @app.before_request
    def _guard() -> Response | None:
        if token is not None:
            given = (
                request.args.get("token")
                or request.headers.get("Authorization", "").removeprefix("Bearer ").strip()
                or request.cookies.get(TOKEN_COOKIE, "")
            )
            if not hmac.compare_digest(given.encode(), token.encode()):
                return Response("401: this dashboard needs its token (?token=...)\n", 401, mimetype="text/plain")
        elif check_host and request.host.rsplit(":", 1)[0] not in LOOPBACK_NAMES:
            return Response("403: unexpected Host header\n", 403, mimetype="text/plain")
        return None

    @app.after_request
    def _headers(response: Response) -> Response:
        response.headers["X-Content-Type-Options"] = "nosniff"
        response.headers["X-Frame-Options"] = "DENY"
        response.headers["Referrer-Policy"] = "no-referrer"
        response.headers.setdefault("Content-Security-Policy", PAGE_CSP)  # a file has its own (FILE_CSP)
        if token is not None and request.args.get("token") == token:
            response.set_cookie(TOKEN_COOKIE, token, httponly=True, samesite="Strict")
        return response

    def run_files(root: int, rel: str) -> RunFiles:
        run = folders.run(root, rel)
        if run is None or not is_run_dir(run):
            abort(404)
        return run

    def page_context(root: int, rel: str) -> dict[str, Any]:
        row = summarize_run(run_files(root, rel))
        return {"run": row, "run_id": row.id, "folders": folders}

    # ---- pages -------------------------------------------------------------------------------------------------
    @app.get("/")
    def runs_page() -> str:
        return render_template("runs.html", folders=[folders.label(i) for i in range(len(folders.roots))])

    @app.get("/compare")
    def compare_page() -> str:
        return render_template("compare.html", run_ids=request.args.getlist("run"))

    for view in ("run", "decisions", "trust"):
        def page(root: int, rel: str = "", _view: str = view) -> str:
            return render_template(f"{_view}.html", **page_context(root, rel))

        app.add_url_rule(f"/{view}/<int:root>/", f"{view}_page_root", page)
        app.add_url_rule(f"/{view}/<int:root>/<path:rel>", f"{view}_page", page)

    # ---- JSON --------------------------------------------------------------------------------------------------
    @app.get("/api/runs")
    def api_runs() -> Response:
        return _json({"runs": [r.as_json() for r in catalog.rows()]})

    def api_route(name: str):  # type: ignore[no-untyped-def]
        def register(fn):  # type: ignore[no-untyped-def]
            app.add_url_rule(f"/api/{name}/<int:root>/", f"api_{name}_root", fn)
            app.add_url_rule(f"/api/{name}/<int:root>/<path:rel>", f"api_{name}", fn)
            return fn
        return register

    def curves(run: RunFiles) -> dict[str, Any]:
        notes: list[str] = []
        return {
            "run": summarize_run(run).as_json(),
            "train": readers.read_monitor_episodes(run, notes),
            "eval": readers.read_evaluations(run, notes),
            "notes": notes,
        }

    @api_route("curves")
    def api_curves(root: int, rel: str = "") -> Response:
        return _json(curves(run_files(root, rel)))

    @api_route("settings")
    def api_settings(root: int, rel: str = "") -> Response:
        run = run_files(root, rel)
        notes: list[str] = []
        settings = readers.read_settings(run, notes)
        return _json({
            **settings, "files": readers.list_files(run), "logs": readers.list_logs(run),
            "action_count": readers.action_count(run), "notes": notes,
        })

    @api_route("trust")
    def api_trust(root: int, rel: str = "") -> Response:
        run = run_files(root, rel)
        notes: list[str] = []
        logs = [name for name in readers.list_logs(run) if not name.startswith("videos/")]
        path = run.file(logs[0]) if logs else None
        costs = episode_costs(path) if path is not None else None
        if costs is not None and costs["problem"]:
            notes.append(costs["problem"])
        return _json({
            "safety": readers.read_safety(run, notes),
            "ep_cost": costs,
            "ep_cost_log": logs[0] if costs is not None else None,
            "adversarial": readers.read_adversarial(run, notes),
            "fairness": readers.read_fairness(run, notes),
            "notes": notes,
        })

    def log_index(run: RunFiles) -> LogIndex:
        log = request.args.get("log", "")
        path = run.file(log) if log in readers.list_logs(run) else None
        if path is None:
            abort(404)
        try:
            index = open_log(path, resolved=True)  # real: not resolved again
        except OSError:  # gone, or no longer a regular file
            abort(404)
        index_in_background(index)
        return index

    @api_route("decisions")
    def api_decisions(root: int, rel: str = "") -> Response:
        index = log_index(run_files(root, rel))
        count = min(int_arg("count", 50), MAX_PAGE_ROWS)
        start, cursor, flt = int_arg("start", 0), int_arg("cursor", 0), row_filter()
        try:
            index.refresh(time_budget=0.05)
            if not flt.is_empty():
                page = index.query(flt, cursor=cursor, limit=count, time_budget=0.5)
            elif request.args.get("tail") == "1":
                page = index.tail(count)
            else:
                page = index.page(start, count)
        except OSError:  # the log went away while it was read
            abort(404)
        return _json({**_page_json(page, index), "filtered": not flt.is_empty()})

    @api_route("episode")
    def api_episode(root: int, rel: str = "") -> Response:
        run = run_files(root, rel)
        index = log_index(run)
        episode, env = int_arg("episode", 0), optional_int("env")
        try:
            page = index.episode_rows(episode, env=env, agent=request.args.get("agent") or None)
        except OSError:
            abort(404)
        return _json({**_page_json(page, index), "video": readers.video_of(run, request.args.get("log", ""))})

    @app.get("/api/compare")
    def api_compare() -> Response:
        runs = []
        for run_id in request.args.getlist("run")[:50]:
            root_text, _, rel = run_id.partition("/")
            if not (root_text.isascii() and root_text.isdigit() and len(root_text) < 10):
                abort(404)
            runs.append(curves(run_files(int(root_text), rel)))
        return _json({"runs": runs})

    # ---- files -------------------------------------------------------------------------------------------------
    @app.get("/file/<int:root>/<path:rel>")
    def file(root: int, rel: str) -> Response:
        path = folders.resolve(root, rel)
        if path is None:
            abort(404)
        try:  # opened once, without following a symlink swapped in since the check; then only the open file is read
            fh = open_regular(path)
        except OSError:  # a folder, FIFO or device; unreadable, gone or swapped since the check
            abort(404)
        return _send_open_file(fh, path.name, as_attachment=request.args.get("download") == "1")

    @app.get("/favicon.ico")
    def favicon() -> Response:
        return Response(status=204)

    @app.get("/static/plotly.min.js")
    def plotly_js() -> Response:
        return Response(_plotly_js(), mimetype="text/javascript", headers={"Cache-Control": "max-age=86400"})

    return app


def _send_open_file(fh: BinaryIO, name: str, as_attachment: bool) -> Response:
    """The open regular file ``fh`` (named ``name``) as a response that cannot run script in the dashboard's origin:
    only the passive types of :data:`INLINE_TYPES` inline, everything else an ``application/octet-stream``
    attachment; :data:`FILE_CSP` and ``nosniff`` on both. Range and conditional requests are answered from the open
    file (its ``fstat``), which the response closes."""
    try:
        st = os.fstat(fh.fileno())
        mimetype = INLINE_TYPES.get(os.path.splitext(name)[1].lower())
        response = send_file(
            fh, mimetype=mimetype or "application/octet-stream", as_attachment=as_attachment or mimetype is None,
            download_name=name, conditional=False, etag=f"{st.st_ino:x}-{st.st_mtime_ns:x}-{st.st_size:x}",
            last_modified=st.st_mtime,
        )
        response.content_length = st.st_size
        response.make_conditional(request.environ, accept_ranges=True, complete_length=st.st_size)
    except BaseException:  # RequestedRangeNotSatisfiable (416) included: the response would not close it
        fh.close()
        raise
    response.headers["Content-Security-Policy"] = FILE_CSP
    response.headers["X-Content-Type-Options"] = "nosniff"
    return response


_PLOTLY: list[str] = []


def _plotly_js() -> str:
    """plotly.js as shipped inside the ``plotly`` Python package (no CDN: the page works offline)."""
    if not _PLOTLY:
        from plotly.offline import get_plotlyjs

        _PLOTLY.append(get_plotlyjs())
    return _PLOTLY[0]


def _page_json(page: Page, index: LogIndex) -> dict[str, Any]:
    return {
        "columns": page.columns, "rows": page.rows, "row_numbers": page.row_numbers,
        "total_rows": page.total_rows, "complete": page.complete, "next_cursor": page.next_cursor,
        "scanned_to": page.scanned_to, "notes": [index.problem] if index.problem else [],
    }


def _clean(value: Any) -> Any:
    """JSON-safe data: NaN and infinities become null (JavaScript's JSON.parse refuses them)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


def _json(data: Any) -> Response:
    response = jsonify(_clean(data))
    response.headers["Cache-Control"] = "no-store"
    return response
