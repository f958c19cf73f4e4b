"""sbagents.dashboard's ``/file/`` route and run-dir readers against a writer in the run dir: a file opened once,
without following a symlink swapped in after the check (at the file's name or at a folder above it), a FIFO swapped
in that neither blocks nor stops the server, content types that cannot run script in the dashboard's origin
(html, svg, js... are attachments; a sandbox CSP and ``nosniff`` on every file), and no token in any log line."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import threading
import urllib.error
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import pytest

pytest.importorskip("flask")

from flask import Flask  # noqa: E402

from sbagents.dashboard.app import create_app  # noqa: E402
from sbagents.dashboard.folders import RunFiles, ServedFolders, open_regular  # noqa: E402
from sbagents.dashboard.server import redact_token  # noqa: E402
from tests.cli_helpers import default_sigint  # noqa: E402
from tests.test_dashboard import RUN, write_run  # noqa: E402

ENV_DIR = "sbagents_SmartHome-v0"
#: What the files outside the served folder hold; no response may contain it.
SECRET = b"s3cr3t-outside-the-served-folder"
INSIDE = b"inside the served folder"
#: Seconds a request may take before a test calls it hung (a guard against deadlocks, not a speed check).
HANG_S = 30
T = TypeVar("T")


@pytest.fixture(autouse=True)
def _cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SBAGENTS_CACHE_DIR", str(tmp_path / "cache"))


def served(folder: Path) -> Flask:
    """The app over ``folder``; exceptions propagate, so a failing route shows its traceback."""
    app = create_app(ServedFolders.from_paths([folder]))
    app.config["PROPAGATE_EXCEPTIONS"] = True
    return app


@pytest.fixture()
def tree(tmp_path: Path) -> dict[str, Path]:
    """A served folder with a run dir (``sub/file.txt`` in it holds :data:`INSIDE`), and an outside folder whose
    ``file.txt``, ``sub/file.txt`` and ``cfg/config.yml`` hold :data:`SECRET`."""
    logs = tmp_path / "logs"
    run_dir = write_run(logs)
    (run_dir / "sub").mkdir()
    (run_dir / "sub" / "file.txt").write_bytes(INSIDE)
    (run_dir / "file.txt").write_bytes(INSIDE)
    outside = tmp_path / "outside"
    (outside / "sub").mkdir(parents=True)
    (outside / "cfg").mkdir()
    (outside / "file.txt").write_bytes(SECRET)
    (outside / "sub" / "file.txt").write_bytes(SECRET)
    (outside / "cfg" / "config.yml").write_bytes(b"secret: " + SECRET + b"\n")
    (outside / "cfg" / "args.yml").write_bytes(b"secret: " + SECRET + b"\n")
    return {"logs": logs, "run": run_dir, "outside": outside}


def swap_to_symlink(path: Path, target: Path) -> None:
    """Replace the file or folder ``path`` by a symlink to ``target`` (what a writer in the run dir can do)."""
    if path.is_dir() and not path.is_symlink():
        path.rename(path.with_name(path.name + ".moved"))
    else:
        path.unlink()
    path.symlink_to(target, target_is_directory=target.is_dir())


def after_check(monkeypatch: pytest.MonkeyPatch, cls: type, method: str, when: Callable[[str], bool],
                swap: Callable[[], None]) -> list[str]:
    """Make ``cls.method`` (a path check: ``ServedFolders.resolve``, ``RunFiles.file``) run ``swap`` once, right
    after it checked a name ``when`` accepts: the window between the check and the open, made certain. Returns the
    names it swapped after."""
    original = getattr(cls, method)
    swapped: list[str] = []

    def checked_then_swapped(self: object, *args: object) -> object:
        result = original(self, *args)
        name = str(args[-1])
        if result is not None and not swapped and when(name):
            swapped.append(name)
            swap()
        return result

    monkeypatch.setattr(cls, method, checked_then_swapped)
    return swapped


# ---------------------------------------------------------------------------------------------------- symlinks
@pytest.mark.parametrize("where", ["name", "folder"])
def test_a_symlink_swapped_in_after_the_check_is_refused(tree: dict[str, Path], monkeypatch: pytest.MonkeyPatch,
                                                         where: str) -> None:
    """``/file/``: the path is checked, then a writer swaps a symlink out of the served folder in, at the file's
    own name or at the folder above it; the file is opened once, without following it: 404, nothing outside."""
    client = served(tree["logs"]).test_client()
    url = f"/file/0/{RUN}/sub/file.txt"
    assert client.get(url).data == INSIDE
    if where == "name":
        def swap() -> None:
            swap_to_symlink(tree["run"] / "sub" / "file.txt", tree["outside"] / "file.txt")
    else:
        def swap() -> None:
            swap_to_symlink(tree["run"] / "sub", tree["outside"] / "sub")
    swapped = after_check(monkeypatch, ServedFolders, "resolve", lambda name: name.endswith("sub/file.txt"), swap)
    response = client.get(url)
    assert swapped and response.status_code == 404 and SECRET not in response.data
    assert (tree["run"] / "sub" / "file.txt").read_bytes() == SECRET  # the swap did lead out
    assert client.get(f"/file/0/{RUN}/file.txt").data == INSIDE  # and the server keeps serving


@pytest.mark.parametrize("where", ["name", "folder"])
def test_run_file_readers_do_not_follow_a_symlink_swapped_in(tree: dict[str, Path], monkeypatch: pytest.MonkeyPatch,
                                                            where: str) -> None:
    """Every reader opens through :meth:`RunFiles.open`: a config file (or its folder) swapped for a symlink out
    after :meth:`RunFiles.file` checked it is a missing file, not the outside file's content."""
    client = served(tree["logs"]).test_client()
    assert client.get(f"/api/settings/0/{RUN}").get_json()["config"]["learning_rate"] == 0.001
    if where == "name":
        def swap() -> None:
            swap_to_symlink(tree["run"] / ENV_DIR / "config.yml", tree["outside"] / "cfg" / "config.yml")
    else:
        def swap() -> None:
            swap_to_symlink(tree["run"] / ENV_DIR, tree["outside"] / "cfg")
    swapped = after_check(monkeypatch, RunFiles, "file", lambda name: name.endswith("config.yml"), swap)
    response = client.get(f"/api/settings/0/{RUN}")
    assert swapped and response.status_code == 200 and SECRET not in response.data


def test_a_log_swapped_for_a_symlink_after_the_check_is_not_paged(tree: dict[str, Path],
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """``/api/decisions``: the log is listed and checked, then swapped for a symlink to an outside CSV: 404."""
    (tree["outside"] / "log.csv").write_bytes(b"env,episode,step,reward\n0,0,0," + SECRET + b"\n")
    client = served(tree["logs"]).test_client()

    def swap() -> None:
        swap_to_symlink(tree["run"] / "transparency.csv", tree["outside"] / "log.csv")

    checks: list[str] = []
    original = RunFiles.file

    def checked_then_swapped(self: RunFiles, name: str) -> Path | None:
        result = original(self, name)
        if name == "transparency.csv" and result is not None:
            checks.append(name)
            if len(checks) == 2:  # listed by list_logs, then checked again for ?log=: the open comes next
                swap()
        return result

    monkeypatch.setattr(RunFiles, "file", checked_then_swapped)
    response = client.get(f"/api/decisions/0/{RUN}?log=transparency.csv")
    assert len(checks) == 2 and response.status_code == 404 and SECRET not in response.data
    assert (tree["run"] / "transparency.csv").read_bytes().endswith(SECRET + b"\n")  # the swap did lead out


def test_open_regular_refuses_symlinks_anywhere_on_the_path(tree: dict[str, Path]) -> None:
    """The opener itself: a real path opens; a symlink as its last component or as a folder above it does not."""
    run_dir = tree["run"]
    with open_regular(run_dir / "sub" / "file.txt") as fh:
        assert fh.read() == INSIDE
    (run_dir / "link.txt").symlink_to(run_dir / "file.txt")  # even one that stays inside: a real path has none
    (run_dir / "linked").symlink_to(run_dir / "sub", target_is_directory=True)
    for path in (run_dir / "link.txt", run_dir / "linked" / "file.txt", run_dir / "sub", run_dir / "nope.txt"):
        with pytest.raises(OSError):
            open_regular(path)


def test_symlinks_that_stay_inside_are_still_served(tree: dict[str, Path]) -> None:
    """A symlink inside the served folder to a file or folder inside it is followed when the path is checked (its
    real path is opened): no symlink was swapped in, so it is served as before."""
    run_dir, client = tree["run"], served(tree["logs"]).test_client()
    (run_dir / "alias.txt").symlink_to("sub/file.txt")
    (tree["logs"] / "latest").symlink_to(run_dir, target_is_directory=True)
    assert client.get(f"/file/0/{RUN}/alias.txt").data == INSIDE
    assert client.get("/file/0/latest/sub/file.txt").data == INSIDE
    assert client.get("/api/settings/0/latest").get_json()["config"]["learning_rate"] == 0.001


# ---------------------------------------------------------------------------------------------------- races
def in_thread(fn: Callable[[], T], release: Path | None = None) -> T:
    """``fn()`` in a thread, failing the test if it blocks (then a FIFO at ``release`` is opened for writing, so
    the blocked reader ends)."""
    out: list[T] = []
    thread = threading.Thread(target=lambda: out.append(fn()), daemon=True)
    thread.start()
    thread.join(HANG_S)
    if thread.is_alive() and release is not None:
        os.close(os.open(release, os.O_WRONLY | os.O_NONBLOCK))
    assert not thread.is_alive(), "a request blocked on a FIFO"
    return out[0]


def race(client_get: Callable[[str], tuple[int, bytes]], url: str, flip: Callable[[bool], None],
         requests: int = 300) -> dict[int, int]:
    """``requests`` GETs of ``url`` while another thread calls ``flip(True)`` (lead out) and ``flip(False)`` (back
    inside) in turn; the statuses counted. No body may hold :data:`SECRET`; every 200 must be the inside file."""
    stop = threading.Event()
    flips = [0]

    def writer() -> None:
        while not stop.is_set():
            flip(flips[0] % 2 == 0)
            flips[0] += 1

    thread = threading.Thread(target=writer, daemon=True)
    thread.start()
    statuses: dict[int, int] = {}
    try:
        for _ in range(requests):
            status, body = in_thread(lambda: client_get(url))
            assert SECRET not in body, f"the outside file came back after {sum(statuses.values())} requests"
            assert status in (200, 404) and (status != 200 or body == INSIDE), (status, body[:80])
            statuses[status] = statuses.get(status, 0) + 1
    finally:
        stop.set()
        thread.join(HANG_S)
    assert flips[0] > 1, "the writer never flipped the file"
    return statuses


def test_a_file_flipping_between_regular_and_symlink_never_leads_out(tree: dict[str, Path]) -> None:
    """The audit's repro: a writer flips ``file.txt`` between a regular file and a symlink out of the served
    folder (each flip an atomic rename) while the dashboard serves it; no response is the outside file."""
    run_dir, client = tree["run"], served(tree["logs"]).test_client()
    regular, link = run_dir / "regular.tmp", run_dir / "link.tmp"

    def flip(out: bool) -> None:
        if out:
            link.symlink_to(tree["outside"] / "file.txt")
            os.replace(link, run_dir / "file.txt")
        else:
            regular.write_bytes(INSIDE)
            os.replace(regular, run_dir / "file.txt")

    def get(url: str) -> tuple[int, bytes]:
        response = client.get(url)
        return response.status_code, response.data

    statuses = race(get, f"/file/0/{RUN}/file.txt", flip)
    assert sum(statuses.values()) == 300


def test_a_folder_flipping_between_folder_and_symlink_never_leads_out(tree: dict[str, Path]) -> None:
    """The same with the folder above the file: ``sub`` flips between the run's folder and a symlink to an outside
    folder that has a ``file.txt`` too."""
    run_dir, client = tree["run"], served(tree["logs"]).test_client()
    sub, moved, link = run_dir / "sub", run_dir / "sub.real", run_dir / "sub.link"
    link.symlink_to(tree["outside"] / "sub", target_is_directory=True)

    def flip(out: bool) -> None:
        if out:
            os.rename(sub, moved)
            os.rename(link, sub)
        else:
            os.rename(sub, link)
            os.rename(moved, sub)

    def get(url: str) -> tuple[int, bytes]:
        response = client.get(url)
        return response.status_code, response.data

    statuses = race(get, f"/file/0/{RUN}/sub/file.txt", flip)
    assert sum(statuses.values()) == 300


# ---------------------------------------------------------------------------------------------------- FIFOs
def test_a_fifo_is_an_error_at_once_and_the_server_keeps_serving(tree: dict[str, Path],
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """A FIFO in the run dir, and one swapped in for a video after its check: 404 without blocking (no writer ever
    opens them), then the next request is served."""
    run_dir, client = tree["run"], served(tree["logs"]).test_client()
    os.mkfifo(run_dir / "pipe.mp4")
    assert in_thread(lambda: client.get(f"/file/0/{RUN}/pipe.mp4").status_code) == 404
    video = run_dir / "videos" / "clip.mp4"

    def swap() -> None:
        video.unlink()
        os.mkfifo(video)

    swapped = after_check(monkeypatch, ServedFolders, "resolve", lambda name: name.endswith("clip.mp4"), swap)
    status = in_thread(lambda: client.get(f"/file/0/{RUN}/videos/clip.mp4").status_code, release=video)
    assert swapped and status == 404
    assert client.get(f"/file/0/{RUN}/file.txt").data == INSIDE
    assert client.get(f"/api/settings/0/{RUN}").status_code == 200


def test_a_file_flipping_between_regular_and_fifo_never_blocks(tree: dict[str, Path]) -> None:
    """The audit's repro: a writer flips ``file.txt`` between a regular file and a FIFO; each request answers (the
    file or 404) instead of waiting for a writer on the FIFO, and the server keeps serving."""
    run_dir, client = tree["run"], served(tree["logs"]).test_client()
    regular, fifo = run_dir / "regular.tmp", run_dir / "fifo.tmp"

    def flip(out: bool) -> None:
        if out:
            os.mkfifo(fifo)
            os.replace(fifo, run_dir / "file.txt")
        else:
            regular.write_bytes(INSIDE)
            os.replace(regular, run_dir / "file.txt")

    def get(url: str) -> tuple[int, bytes]:
        response = client.get(url)
        return response.status_code, response.data

    statuses = race(get, f"/file/0/{RUN}/file.txt", flip, requests=200)
    assert sum(statuses.values()) == 200
    assert client.get(f"/file/0/{RUN}/command.txt").status_code == 200


# ---------------------------------------------------------------------------------------------------- types
ACTIVE = {  # name: content a browser would run as script if it rendered the file in the dashboard's origin
    "evil.html": b"<script>fetch('/api/runs')</script>", "evil.htm": b"<script>1</script>",
    "evil.svg": b'<svg xmlns="http://www.w3.org/2000/svg"><script>1</script></svg>',
    "evil.js": b"fetch('/api/runs')", "evil.mjs": b"export default 1", "evil.xml": b"<a/>",
    "evil.xhtml": b'<html xmlns="http://www.w3.org/1999/xhtml"><script>1</script></html>',
    "evil.pdf": b"%PDF-1.4", "evil.swf": b"FWS", "noext": b"<script>1</script>", "evil.csv.gz": b"\x1f\x8b",
}
PASSIVE = {"a.png": "image/png", "a.jpg": "image/jpeg", "a.gif": "image/gif", "videos/clip.mp4": "video/mp4",
           "a.webm": "video/webm", "a.csv": "text/csv", "a.json": "application/json", "a.txt": "text/plain",
           "a.yml": "text/plain"}


def assert_file_headers(headers: object) -> None:
    csp = headers["Content-Security-Policy"]  # type: ignore[index]
    assert headers["X-Content-Type-Options"] == "nosniff"  # type: ignore[index]
    assert "sandbox" in [d.strip().split(" ")[0] for d in csp.split(";")], csp
    assert "default-src 'none'" in csp and "script-src" not in csp


def test_active_types_are_attachments_in_a_sandbox(tree: dict[str, Path]) -> None:
    """The audit's repro: ``evil.html``, ``.svg``, ``.js`` ... in a run dir were served inline as their type, from
    the dashboard's origin. Now anything not on the list of passive types is an ``application/octet-stream``
    attachment, and every file has ``nosniff`` and a sandbox CSP."""
    run_dir, client = tree["run"], served(tree["logs"]).test_client()
    for name, data in ACTIVE.items():
        (run_dir / name).write_bytes(data)
        response = client.get(f"/file/0/{RUN}/{name}")
        assert response.status_code == 200 and response.data == data, name
        assert response.headers["Content-Disposition"].startswith("attachment"), name
        assert response.mimetype == "application/octet-stream", name
        assert_file_headers(response.headers)


def test_passive_types_are_inline_with_their_type_in_a_sandbox(tree: dict[str, Path]) -> None:
    """Images, videos and plain data stay viewable in the page (inline, with their type, ranges for seeking),
    with the same sandbox CSP and ``nosniff``; ``?download=1`` makes any of them an attachment."""
    run_dir, client = tree["run"], served(tree["logs"]).test_client()
    for name, mimetype in PASSIVE.items():
        if not (run_dir / name).exists():
            (run_dir / name).write_bytes(b"0123456789")
        response = client.get(f"/file/0/{RUN}/{name}")
        assert response.status_code == 200 and response.mimetype == mimetype, name
        assert response.headers["Content-Disposition"].startswith("inline"), name
        assert_file_headers(response.headers)
        download = client.get(f"/file/0/{RUN}/{name}?download=1")
        assert download.headers["Content-Disposition"].startswith("attachment"), name
    part = client.get(f"/file/0/{RUN}/videos/clip.mp4", headers={"Range": "bytes=4-7"})
    assert part.status_code == 206 and part.data == b"ftyp" and part.headers["Content-Range"].endswith("/76")
    assert_file_headers(part.headers)
    etag = part.headers["ETag"]
    assert client.get(f"/file/0/{RUN}/a.png", headers={"If-None-Match": etag}).status_code == 200
    same = client.get(f"/file/0/{RUN}/videos/clip.mp4", headers={"If-None-Match": etag})
    assert same.status_code == 304
    assert client.get(f"/file/0/{RUN}/a.png", headers={"Range": "bytes=99-"}).status_code == 416
    page = client.get(f"/run/0/{RUN}")
    assert "default-src 'self'" in page.headers["Content-Security-Policy"]  # the pages keep theirs


# ---------------------------------------------------------------------------------------------------- token logs
def test_redact_token_hides_every_token_value() -> None:
    lines = {
        '"GET /?token=s3cret-token HTTP/1.1" 200 -': '"GET /?token=*** HTTP/1.1" 200 -',
        '"GET /api/runs?x=1&token=s3cret-token&y=2 HTTP/1.1" 200 -': '"GET /api/runs?x=1&token=***&y=2 HTTP/1.1" 200 -',
        "code 400, message Bad request syntax ('GET /?%74oken=s3cret;x HTTP/1.1 x')":
            "code 400, message Bad request syntax ('GET /?%74oken=*** HTTP/1.1 x')",
        '"GET /?tokens=1&a=token HTTP/1.1" 200 -': '"GET /?tokens=1&a=token HTTP/1.1" 200 -',
    }
    for line, redacted in lines.items():
        assert redact_token(line) == redacted


def test_the_verbose_request_log_has_no_token(tree: dict[str, Path]) -> None:
    """``-v`` logs every request line; with the token in the URL (``?token=``, percent-encoded, in a bad request
    line), none of the server's output holds it: the start line says where to add it, the log says ``token=***``."""
    token = "tok-0123456789-abcdef"
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "SBAGENTS_DASHBOARD_TOKEN": token}
    # a subprocess on purpose: the real server and its request log
    proc = subprocess.Popen([sys.executable, "-m", "sbagents.dashboard", "-f", str(tree["logs"]), "--port", "0", "-v"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            preexec_fn=default_sigint)
    try:
        first = proc.stdout.readline() if proc.stdout else ""
        found = re.search(r"http://127\.0\.0\.1:(\d+)/", first)
        assert found and token not in first, first
        base = f"http://127.0.0.1:{found[1]}"
        with urllib.request.urlopen(f"{base}/api/runs?token={token}") as response:
            assert response.status == 200
        with urllib.request.urlopen(f"{base}/file/0/{RUN}/command.txt?x=1&%74oken={token}") as response:
            assert response.read().startswith(b"python -m sbagents.train")
        with pytest.raises(urllib.error.HTTPError):
            urllib.request.urlopen(f"{base}/api/runs?token=wrong-{token}")
        import socket

        with socket.create_connection(("127.0.0.1", int(found[1]))) as raw:  # a bad request line, quoted in the log
            raw.sendall(f"GET /?token={token} HTTP/1.1 extra\r\n\r\n".encode())
            assert b"400" in raw.recv(4096)
    finally:
        proc.send_signal(2)
        out, err = proc.communicate(timeout=HANG_S)
    assert proc.returncode == 0 and "Traceback" not in err
    err = re.sub(r"\x1b\[[0-9;]*m", "", err)  # werkzeug colours error lines where it thinks a terminal reads them
    assert token not in out + err and err.count("token=***") == 4, err  # the four requests that carried it
    assert "/api/runs?token=*** HTTP/1.1" in err and '"GET /?token=*** HTTP/1.1 extra" 400' in err
