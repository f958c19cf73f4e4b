"""The dashboard's Flask app: read-only pages and JSON endpoints over the served log folders.

Pages (HTML shells filled by ``static/dashboard.js``): ``/`` runs, ``/run/<folder>/<run>`` one run,
``/decisions/<folder>/<run>`` its transparency logs, ``/trust/<folder>/<run>`` safety, attacks and fairness,
``/compare?run=<id>&run=<id>`` several runs' curves. JSON under ``/api/``; files under ``/file/<folder>/<path>``.
Every path goes through :class:`~sbagents.dashboard.folders.ServedFolders` (404 outside the folders).
"""

from __future__ import annotations

import hmac
import math
import threading
from pathlib import Path
from typing import Any

from flask import Flask, Response, abort, jsonify, render_template, request, send_file

from sbagents.dashboard import readers
from sbagents.dashboard.episode_costs import episode_costs
from sbagents.dashboard.folders import ServedFolders
from sbagents.dashboard.logindex import LogIndex, RowFilter, open_log
from sbagents.dashboard.runs import RUN_MARKERS, RunCatalog, summarize_run

#: Cookie that carries the token after the first request that had it in the URL.
TOKEN_COOKIE = "sbagents_dashboard_token"
#: Most rows one decisions request returns.
MAX_PAGE_ROWS = 1000
LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]", "::1")


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
        response.headers["Content-Security-Policy"] = (
            "default-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data: blob:; "
            "media-src 'self'; connect-src 'self'; object-src 'none'; frame-ancestors 'none'"
        )
        if token is not None and request.args.get("token") == token:
            response.set_cookie(TOKEN_COOKIE, token, httponly=True, samesite="Strict")
        return response

    def run_dir(root: int, rel: str) -> Path:
        path = folders.resolve(root, rel)
        if path is None or not path.is_dir() or not any((path / m).exists() for m in RUN_MARKERS):
            abort(404)
        return path

    def page_context(root: int, rel: str) -> dict[str, Any]:
        row = summarize_run(folders, root, rel)
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
            run_dir(root, rel)
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

    @api_route("curves")
    def api_curves(root: int, rel: str = "") -> Response:
        path = run_dir(root, rel)
        notes: list[str] = []
        return _json({
            "run": summarize_run(folders, root, rel).as_json(),
            "train": readers.read_monitor_episodes(path, notes),
            "eval": readers.read_evaluations(path, notes),
            "notes": notes,
        })

    @api_route("settings")
    def api_settings(root: int, rel: str = "") -> Response:
        path = run_dir(root, rel)
        notes: list[str] = []
        settings = readers.read_settings(path, notes)
        return _json({
            **settings, "files": readers.list_files(path), "logs": readers.list_logs(path),
            "action_count": readers.action_count(path), "notes": notes,
        })

    @api_route("trust")
    def api_trust(root: int, rel: str = "") -> Response:
        path = run_dir(root, rel)
        notes: list[str] = []
        logs = [p for p in readers.list_logs(path) if not p.startswith("videos/")]
        costs = episode_costs(path / logs[0]) if logs else None
        return _json({
            "safety": readers.read_safety(path, notes),
            "ep_cost": costs,
            "ep_cost_log": logs[0] if logs else None,
            "adversarial": readers.read_adversarial(path, notes),
            "fairness": readers.read_fairness(path, notes),
            "notes": notes,
        })

    def log_index(path: Path) -> LogIndex:
        log = request.args.get("log", "")
        if log not in readers.list_logs(path):
            abort(404)
        index = open_log(path / log)
        _index_in_background(index)
        return index

    @api_route("decisions")
    def api_decisions(root: int, rel: str = "") -> Response:
        index = log_index(run_dir(root, rel))
        count = min(_int_arg("count", 50), MAX_PAGE_ROWS)
        flt = _row_filter()
        index.refresh(time_budget=0.05)
        if not flt.is_empty():
            page = index.query(flt, cursor=_int_arg("cursor", 0), limit=count, time_budget=0.5)
        elif request.args.get("tail") == "1":
            page = index.tail(count)
        else:
            page = index.page(_int_arg("start", 0), count)
        return _json({**_page_json(page), "filtered": not flt.is_empty()})

    @api_route("episode")
    def api_episode(root: int, rel: str = "") -> Response:
        path = run_dir(root, rel)
        index = log_index(path)
        env = request.args.get("env")
        page = index.episode_rows(
            _int_arg("episode", 0), env=int(env) if env not in (None, "") else None,
            agent=request.args.get("agent") or None,
        )
        log = request.args.get("log", "")
        video = None
        if log.startswith("videos/"):
            for suffix in readers.VIDEO_SUFFIXES:
                candidate = (path / log).with_suffix(suffix)
                if candidate.exists():
                    video = candidate.relative_to(path).as_posix()
        return _json({**_page_json(page), "video": video})

    @app.get("/api/compare")
    def api_compare() -> Response:
        runs = []
        for run_id in request.args.getlist("run")[:50]:
            root_text, _, rel = run_id.partition("/")
            if not root_text.isdigit():
                abort(404)
            path = run_dir(int(root_text), rel)
            notes: list[str] = []
            runs.append({
                "run": summarize_run(folders, int(root_text), rel).as_json(),
                "train": readers.read_monitor_episodes(path, notes),
                "eval": readers.read_evaluations(path, notes),
                "notes": notes,
            })
        return _json({"runs": runs})

    # ---- files -------------------------------------------------------------------------------------------------
    @app.get("/file/<int:root>/<path:rel>")
    def file(root: int, rel: str) -> Response:
        path = folders.resolve(root, rel)
        if path is None or not path.is_file():
            abort(404)
        return send_file(path, conditional=True, as_attachment=request.args.get("download") == "1")

    @app.get("/favicon.ico")
    def favicon() -> Response:
        return Response(status=204)

    @app.get("/static/plotly.min.js")
    def plotly_js() -> Response:
        return Response(_plotly_js(), mimetype="text/javascript", headers={"Cache-Control": "max-age=86400"})

    return app


_PLOTLY: list[str] = []


def _plotly_js() -> str:
    """plotly.js as shipped inside the ``plotly`` Python package (no CDN: the page works offline)."""
    if not _PLOTLY:
        from plotly.offline import get_plotlyjs

        _PLOTLY.append(get_plotlyjs())
    return _PLOTLY[0]


_INDEXING: set[int] = set()
_INDEXING_LOCK = threading.Lock()


def _index_in_background(index: LogIndex) -> None:
    """Index the whole log once in a daemon thread (pages asked for meanwhile are served from what is indexed)."""
    with _INDEXING_LOCK:
        if id(index) in _INDEXING:
            return
        _INDEXING.add(id(index))
    threading.Thread(target=index.refresh, name="sbagents-log-index", daemon=True).start()


def _int_arg(name: str, default: int) -> int:
    value = request.args.get(name, "")
    try:
        return max(int(value), 0) if value != "" else default
    except ValueError:
        abort(400, f"{name} must be an integer, got {value!r}")


def _float_arg(name: str) -> float | None:
    value = request.args.get(name, "")
    try:
        return float(value) if value != "" else None
    except ValueError:
        abort(400, f"{name} must be a number, got {value!r}")


def _row_filter() -> RowFilter:
    episode, env = request.args.get("episode", ""), request.args.get("env", "")
    step_min, step_max = _float_arg("step_min"), _float_arg("step_max")
    return RowFilter(
        episode=_int_arg("episode", 0) if episode != "" else None,
        env=_int_arg("env", 0) if env != "" else None,
        agent=request.args.get("agent") or None,
        step_min=int(step_min) if step_min is not None else None,
        step_max=int(step_max) if step_max is not None else None,
        reward_min=_float_arg("reward_min"),
        reward_max=_float_arg("reward_max"),
        violations_only=request.args.get("violations") == "1",
    )


def _page_json(page: Any) -> dict[str, Any]:
    return {
        "columns": page.columns, "rows": page.rows, "row_numbers": page.row_numbers,
        "total_rows": page.total_rows, "complete": page.complete, "next_cursor": page.next_cursor,
        "scanned_to": page.scanned_to,
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
