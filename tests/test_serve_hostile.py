"""Hostile input to ``python -m sbagents.serve``: nothing a client sends ends the server or drops a connection
without a reply, and corrupt model files are one line and exit 2.

The policies are tiny ONNX graphs made here (a linear Box policy, an int64 Discrete one) with their sidecars: the
server is what is under test, and it runs with torch, SB3 and gymnasium unimportable, as on an edge device.
"""

from __future__ import annotations

import contextlib
import csv
import http.client
import io
import json
import math
import os
import re
import select
import socket
import subprocess
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import pytest
from cli_helpers import serve_command
from onnx import TensorProto, helper, numpy_helper

from sbagents.deploy.http_serving import (
    CONNECTION_TIMEOUT,
    MAX_BODY,
    MAX_CONNECTIONS,
    REQUEST_TIMEOUT,
    PolicyHTTPServer,
    bind,
    expected_hosts,
    host_allowed,
    split_host,
)
from sbagents.deploy.serving import (
    FLOAT32_MAX,
    MAX_REQUEST_BYTES,
    DecisionLog,
    Policy,
    ServeError,
    decide,
    read_lines,
    serve,
)

try:
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st
except ImportError:  # in the test extra (pip install -e '.[test]'); only the property tests need it
    given = None  # type: ignore[assignment]

ROOT = Path(__file__).resolve().parents[1]
OBS_NAMES = ("Temperature", "Light_Level", "Time", "Preferred_Temp", "Preferred_Light")
ACTION_NAMES = ("Action_Temp", "Action_Light")
#: the Box policy: action = obs @ W (linear, so observations near the float32 limit overflow to inf)
W = (np.arange(10, dtype=np.float32).reshape(5, 2) / 10 - 0.2).astype(np.float32)
GOOD = [[22.0, 55.0, 3.0, 24.0, 70.0], [19.5, 80.0, 23.0, 21.0, 52.0]]


def _num(*values: object) -> bytes:
    return json.dumps(list(values)).encode()


#: (what, line or body, a part of the error reply); each is one line (no b"\n" inside)
HOSTILE: list[tuple[str, bytes, str]] = [
    ("400-digit integer", b"[" + b"9" * 400 + b", 55, 3, 24, 70]", "400-digit integer"),
    ("5000-digit integer", b"[" + b"9" * 5000 + b", 55, 3, 24, 70]", "5000-digit integer"),
    ("100,000 nested [", b"[" * 100_000, f"more than {MAX_REQUEST_BYTES} bytes"),
    ("30,000 nested [ (within the size limit)", b"[" * 30_000, "nested too deeply"),
    ("1e999", b"[1e999, 55, 3, 24, 70]", "not a finite number"),
    ("a 400-digit float", b"[" + b"9" * 400 + b".5, 55, 3, 24, 70]", "not a finite number"),
    ("beyond float32", b"[1e39, 55, 3, 24, 70]", "float32 range"),
    ("NaN", b"[NaN, 55, 3, 24, 70]", "NaN"),
    ("Infinity", b"[22, Infinity, 3, 24, 70]", "Infinity"),
    ("-Infinity", b"[22, 55, -Infinity, 24, 70]", "-Infinity"),
    ("non-UTF-8 bytes", b"[22, 55, \xff\xfe, 24, 70]", "not UTF-8"),
    ("wrong length", _num(22, 55), "expected 5 values, got 2"),
    ("a boolean", b"[true, 55, 3, 24, 70]", "not a finite number: True"),
    ("null", b"null", "JSON list or object"),
    ("a string", b'"hello"', "JSON list or object"),
    ("a nested list", json.dumps([GOOD[0]]).encode(), "expected 5 values, got 1"),
    ("a string value", b'[22, "55", 3, 24, 70]', "not a finite number"),
    ("2,000 unknown keys", json.dumps({f"k{i}": i for i in range(2000)}).encode(), "more)"),
    ("missing keys", json.dumps(dict(zip(OBS_NAMES[:3], GOOD[0], strict=False))).encode(), "missing keys"),
    ("a repeated key", ("{" + ", ".join(f'"{k}": 1' for k in (*OBS_NAMES, "Time")) + "}").encode(),
     "key 'Time' is given twice"),
    ("empty line", b"", "empty observation"),
    ("blank line", b"  \t ", "empty observation"),
    ("over-long line", b"[" + b"1.0, " * 40_000 + b"1.0]", f"more than {MAX_REQUEST_BYTES} bytes"),
    ("a NUL byte", b"\x00", "bad JSON"),
    ("a lone surrogate", b'["\\ud800", 55, 3, 24, 70]', "not a finite number"),
    ("a byte order mark", "\ufeff[22, 55, 3, 24, 70]".encode(), "bad JSON"),
    ("trailing garbage", b"[22, 55, 3, 24, 70] x", "bad JSON"),
    ("an actual overflow in the policy", _num(3e38, 3e38, 3e38, 3e38, 3e38), "non-finite action"),
]


@dataclass
class Models:
    box: Path  #: float32 (batch, 5) -> float32 (batch, 2), sidecar with the SmartHome names
    discrete: Path  #: int64 (batch,) -> int64 (batch,) = index mod 3, sidecar with Discrete(25)


def _save(nodes: list[Any], inputs: list[Any], outputs: list[Any], weights: list[Any], path: Path) -> Path:
    model = helper.make_model(helper.make_graph(nodes, path.stem, inputs, outputs, weights),
                              opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.save(model, path)
    return path


def _box_model(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "policy.json").write_text(json.dumps({"obs_names": OBS_NAMES, "action_names": ACTION_NAMES}))
    return _save([helper.make_node("MatMul", ["obs", "W"], ["action"])],
                 [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", 5])],
                 [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", 2])],
                 [numpy_helper.from_array(W, "W")], folder / "policy.onnx")


@pytest.fixture(scope="module")
def models(tmp_path_factory: pytest.TempPathFactory) -> Models:
    root = tmp_path_factory.mktemp("models")
    box = _box_model(root / "box")
    disc = root / "discrete"
    disc.mkdir()
    (disc / "policy.json").write_text(json.dumps({"obs_names": ["cell"], "action_names": ["move"],
                                                  "observation_space": {"type": "discrete", "n": 25, "start": 0}}))
    _save([helper.make_node("Mod", ["obs", "three"], ["action"])],
          [helper.make_tensor_value_info("obs", TensorProto.INT64, ["batch"])],
          [helper.make_tensor_value_info("action", TensorProto.INT64, ["batch"])],
          [numpy_helper.from_array(np.array(3, np.int64), "three")], disc / "policy.onnx")
    return Models(box, disc / "policy.onnx")


def _expected(obs: list[float]) -> list[float]:
    return [float(a) for a in np.asarray(obs, dtype=np.float32) @ W]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT)}


# -- stdin/stdout ---------------------------------------------------------------------------------------------------

def test_stdin_answers_every_hostile_line_and_goes_on(models: Models, tmp_path: Path) -> None:
    """Each hostile line gets an error reply and the good line after it its action; rc 0 at EOF, stderr silent."""
    assert all(b"\n" not in line for _, line, _ in HOSTILE)
    lines: list[bytes] = []
    for i, (_, line, _) in enumerate(HOSTILE):
        lines += [line, json.dumps(GOOD[i % 2]).encode()]
    log = tmp_path / "decisions.csv"
    done = subprocess.run(serve_command("--model", str(models.box), "--csv", str(log)), input=b"\n".join(lines) + b"\n",
                          capture_output=True, env=_env(), timeout=120)
    assert done.returncode == 0 and done.stderr == b"", done.stderr.decode(errors="replace")[-2000:]
    replies = [json.loads(r) for r in done.stdout.decode().splitlines()]
    assert len(replies) == 2 * len(HOSTILE)
    for i, (what, _, reason) in enumerate(HOSTILE):
        error, action = replies[2 * i], replies[2 * i + 1]
        assert isinstance(error, dict) and reason in error["error"] and len(error["error"]) < 400, (what, error)
        assert action == pytest.approx(_expected(GOOD[i % 2]), abs=1e-4), what
    rows = list(csv.reader(log.open()))
    assert len(rows) == 1 + len(HOSTILE)  # the header and the good lines only


def test_stdin_discrete_range_and_types(models: Models) -> None:
    lines = ["3", "[7]", "24", "25", "-1", "3.5", "1e300", "[3, 4]", "true", "9" * 400, "4.0"]
    done = subprocess.run(serve_command("--model", str(models.discrete)), input="\n".join(lines) + "\n",
                          capture_output=True, text=True, env=_env(), timeout=60)
    assert done.returncode == 0 and done.stderr == ""
    replies = [json.loads(r) for r in done.stdout.splitlines()]
    assert replies[:3] == [0, 1, 0] and replies[-1] == 1
    for reply in replies[3:-1]:
        assert isinstance(reply, dict) and "error" in reply
    assert "integer in [0, 25)" in replies[3]["error"] and "integer in [0, 25)" in replies[6]["error"]


@pytest.fixture(scope="module")
def box_policy(models: Models) -> Policy:
    return Policy(models.box)


def test_read_lines_skips_over_long_lines_and_keeps_the_rest(box_policy: Policy) -> None:
    data = b"short\n" + b"x" * 20 + b"\n" + b"y" * 8 + b"\n" + b"z" * 9 + b"\nlast"
    assert list(read_lines(io.BytesIO(data), limit=8)) == [b"short", None, b"y" * 8, None, b"last"]
    out = io.StringIO()
    assert serve(box_policy, io.BytesIO(b"[1, 2, 3, 4, 5]\n\nnot json\n"), out) == (1, 2)
    assert len(out.getvalue().splitlines()) == 3


# -- HTTP -----------------------------------------------------------------------------------------------------------

def _start(*args: str) -> tuple[subprocess.Popen[str], int]:
    proc = subprocess.Popen(serve_command(*args), stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=_env())
    assert proc.stderr is not None
    ready, _, _ = select.select([proc.stderr], [], [], 60)
    line = proc.stderr.readline() if ready else ""
    found = re.search(r"http://127\.0\.0\.1:(\d+)/", line)
    if found is None:
        proc.kill()
        raise AssertionError(f"the server did not start: {line!r}")
    return proc, int(found.group(1))


def _stop(proc: subprocess.Popen[str]) -> str:
    proc.terminate()
    _, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0, stderr
    return stderr


@pytest.fixture(scope="module")
def http_server(models: Models) -> Iterator[int]:
    """``serve --http 127.0.0.1:0`` of the Box policy (torch blocked); its port. It must stop cleanly."""
    proc, port = _start("--model", str(models.box), "--http", "127.0.0.1:0")
    yield port
    assert "Traceback" not in _stop(proc)


def _post(conn: http.client.HTTPConnection, body: bytes, headers: dict[str, str] | None = None,
          path: str = "/", method: str = "POST") -> tuple[int, Any]:
    conn.request(method, path, body=body, headers={"Content-Type": "application/json", **(headers or {})})
    reply = conn.getresponse()
    data = reply.read()
    assert reply.getheader("Content-Type") == "application/json"
    return reply.status, json.loads(data) if data else None


def _good(conn: http.client.HTTPConnection, i: int = 0) -> None:
    status, action = _post(conn, json.dumps(GOOD[i % 2]).encode())
    assert status == 200 and action == pytest.approx(_expected(GOOD[i % 2]), abs=1e-4)


def test_http_answers_every_hostile_body_and_goes_on(http_server: int) -> None:
    conn = http.client.HTTPConnection("127.0.0.1", http_server, timeout=30)
    for i, (what, body, reason) in enumerate(HOSTILE):
        if len(body) > MAX_BODY:  # refused from its Content-Length; that connection is closed after the reply
            big = http.client.HTTPConnection("127.0.0.1", http_server, timeout=30)
            status, error = _post(big, body)
            assert status == 413 and f"at most {MAX_BODY}" in error["error"], what
            big.close()
        else:
            status, error = _post(conn, body)
            assert status == 400 and reason in error["error"], (what, error)
        _good(conn, i)  # the same kept-alive connection still answers


def _raw(port: int, data: bytes, method: str = "GET", end: bool = False) -> tuple[int, Any]:
    """Send ``data`` as it is (then the end of the stream when ``end``) and read one reply (its JSON body, or None
    when it has none)."""
    with socket.create_connection(("127.0.0.1", port), timeout=30) as sock:
        sock.sendall(data)
        if end:
            sock.shutdown(socket.SHUT_WR)
        reply = http.client.HTTPResponse(sock, method=method)
        reply.begin()
        body = reply.read()
        assert reply.getheader("Content-Type") == "application/json"
        return reply.status, json.loads(body) if body else None


def test_http_malformed_requests_get_a_json_reply(http_server: int) -> None:
    host = f"Host: 127.0.0.1:{http_server}\r\n".encode()
    json_post = b"POST / HTTP/1.1\r\n" + host + b"Content-Type: application/json\r\n"
    cases: list[tuple[bytes, int, str]] = [
        (b"GARBAGE\r\n\r\n", 400, ""),  # "": the standard library's words
        (b"POST / HTTP/9.9\r\n\r\n", 400, "send HTTP/1.1"),  # not the standard library's 505: no answer is a 5xx
        (b"GET /" + b"a" * 70_000 + b" HTTP/1.1\r\n\r\n", 414, ""),
        (b"GET / HTTP/1.1\r\n" + host + b"X-Big: " + b"a" * 70_000 + b"\r\n\r\n", 431, ""),
        (b"GET / HTTP/1.1\r\n" + host + b"".join(b"X-%d: 1\r\n" % i for i in range(120)) + b"\r\n", 431, ""),
        (json_post + b"Content-Length: \xb2\r\n\r\n[1]", 400, "Content-Length must be one byte count"),
        (json_post + b"Content-Length: " + b"9" * 5000 + b"\r\n\r\n", 400, "Content-Length must be"),
        (json_post + b"Content-Length: 3\r\nContent-Length: 4\r\n\r\n[1]", 400, "Content-Length must be"),
        (json_post + b"Content-Length: -3\r\n\r\n", 400, "Content-Length must be"),
        (json_post + b"\r\n", 411, "Content-Length is required"),
        (json_post + b"Transfer-Encoding: chunked\r\n\r\n3\r\n[1]\r\n0\r\n\r\n", 411, "chunked"),
        (b"OPTIONS / HTTP/1.1\r\n" + host + b"\r\n", 405, "OPTIONS is not served"),
        (b"DELETE / HTTP/1.1\r\n" + host + b"\r\n", 405, "DELETE is not served"),
        (b"BREW / HTTP/1.1\r\n" + host + b"\r\n", 405, "BREW is not served"),  # not the standard library's 501
        (b"B" * 5000 + b" / HTTP/1.1\r\n" + host + b"\r\n", 405, "..."),  # the method is not echoed in full
    ]
    for data, status, reason in cases:
        got, error = _raw(http_server, data)
        assert got == status and isinstance(error["error"], str) and reason in error["error"], (data[:60], got, error)
    assert _raw(http_server, b"HEAD / HTTP/1.1\r\n" + host + b"\r\n", method="HEAD") == (405, None)  # no body
    got, error = _raw(http_server, json_post + b"Content-Length: 10\r\n\r\n[1, 2]", end=True)  # then it stops
    assert got == 400 and "the body ended after 6 of its 10 bytes" in error["error"]
    _good(http.client.HTTPConnection("127.0.0.1", http_server, timeout=30))


def test_http_content_type_must_be_json(http_server: int) -> None:
    conn = http.client.HTTPConnection("127.0.0.1", http_server, timeout=30)
    body = json.dumps(GOOD[0]).encode()
    for content_type in ("text/plain", "application/x-www-form-urlencoded", "multipart/form-data; boundary=x",
                         "application/jsonx", "json"):
        status, error = _post(conn, body, {"Content-Type": content_type})
        assert status == 415 and "application/json" in error["error"], content_type
    conn.putrequest("POST", "/")  # no Content-Type at all
    conn.putheader("Content-Length", str(len(body)))
    conn.endheaders(body)
    reply = conn.getresponse()
    assert reply.status == 415 and "(none)" in json.loads(reply.read())["error"]
    for content_type in ("application/json", "application/json; charset=utf-8", "Application/JSON"):
        status, action = _post(conn, body, {"Content-Type": content_type})
        assert status == 200 and action == pytest.approx(_expected(GOOD[0]), abs=1e-4), content_type


def test_http_host_header_must_name_the_server(http_server: int) -> None:
    port = http_server
    body = json.dumps(GOOD[0]).encode()
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    for host in ("evil.example", f"evil.example:{port}", f"127.0.0.1.nip.io:{port}", f"127.0.0.1:{port + 1}",
                 "localhost", f"192.168.1.10:{port}", f"localhost:{port}, evil.example"):
        for method, path in (("POST", "/"), ("GET", "/")):  # the policy's names are not readable either
            status, error = _post(conn, body if method == "POST" else b"", {"Host": host}, path, method)
            assert status == 421 and "does not name this server" in error["error"], (host, method)
            assert f"localhost:{port}" in error["error"] and "--allow-any-host" in error["error"]
    for host in (f"localhost:{port}", f"LocalHost:{port}", f"127.0.0.1:{port}", f"127.0.0.2:{port}",
                 f"[::1]:{port}"):
        status, action = _post(conn, body, {"Host": host})
        assert status == 200 and action == pytest.approx(_expected(GOOD[0]), abs=1e-4), host
    missing = _raw(port, b"GET / HTTP/1.1\r\n\r\n")  # HTTP/1.1 without a Host
    assert missing[0] == 421
    two = _raw(port, f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nHost: evil.example\r\n\r\n".encode())
    assert two[0] == 421


def test_allow_any_host_opts_out_of_the_host_check(models: Models) -> None:
    proc, port = _start("--model", str(models.box), "--http", "127.0.0.1:0", "--allow-any-host")
    try:
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
        status, action = _post(conn, json.dumps(GOOD[1]).encode(), {"Host": "evil.example"})
        assert status == 200 and action == pytest.approx(_expected(GOOD[1]), abs=1e-4)
        status, _ = _post(conn, json.dumps(GOOD[1]).encode(), {"Host": "evil.example", "Content-Type": "text/plain"})
        assert status == 415  # the Content-Type check stays
    finally:
        assert "1 decisions, 0 malformed requests, 1 refused" in _stop(proc)


def test_host_rules() -> None:
    allowed: list[tuple[str, int, str]] = [
        ("127.0.0.1", 8000, "127.0.0.1:8000"), ("127.0.0.1", 8000, "localhost:8000"),
        ("127.0.0.1", 8000, "LOCALHOST:8000"), ("127.0.0.1", 8000, "[::1]:8000"), ("::1", 8000, "[::1]:8000"),
        ("localhost", 8000, "127.0.0.1:8000"), ("127.0.0.1", 80, "localhost"), ("127.0.0.1", 80, "localhost:"),
        ("0.0.0.0", 8000, "192.168.1.10:8000"), ("0.0.0.0", 8000, "localhost:8000"), ("::", 8000, "[fe80::1]:8000"),
        ("hub.local", 8000, "hub.local:8000"), ("hub.local", 8000, "HUB.local:8000"),
        ("192.168.1.10", 8000, "192.168.1.10:8000"),
    ]
    refused: list[tuple[str, int, str | None]] = [
        ("127.0.0.1", 8000, None), ("127.0.0.1", 8000, ""), ("127.0.0.1", 8000, "localhost"),
        ("127.0.0.1", 8000, "localhost:8001"), ("127.0.0.1", 8000, "evil.example:8000"),
        ("127.0.0.1", 8000, "localhost.evil.example:8000"), ("127.0.0.1", 8000, "[::1:8000"),
        ("127.0.0.1", 8000, "::1:8000"), ("127.0.0.1", 8000, "localhost:8000:1"), ("127.0.0.1", 8000, "localhost:80a"),
        ("127.0.0.1", 8000, "[evil.example]:8000"), ("127.0.0.1", 8000, "192.168.1.10:8000"),
        ("0.0.0.0", 8000, "hub.local:8000"), ("0.0.0.0", 8000, "192.168.1.10:9000"),
        ("hub.local", 8000, "localhost:8000"), ("hub.local", 8000, "192.168.1.10:8000"),
        ("192.168.1.10", 8000, "192.168.1.11:8000"), ("192.168.1.10", 8000, "localhost:8000"),
    ]
    for bound, port, header in allowed:
        assert host_allowed(header, bound, port), (bound, header)
    for bound, port, given_header in refused:
        assert not host_allowed(given_header, bound, port), (bound, given_header)
    assert split_host("[::1]:8000") == ("::1", 8000) and split_host("Hub.Local") == ("hub.local", None)
    assert "[::1]:8000" not in expected_hosts("127.0.0.1", 8000) and expected_hosts("hub.local", 80) == "hub.local:80"


def test_fifty_clients_connecting_at_once_all_get_answers(http_server: int) -> None:
    """50 threads released by one barrier open a connection each and send 20 observations: 1,000 answers, no
    connection reset (the listen queue is 128, not http.server's 5)."""
    clients, per_client = 50, 20
    barrier = threading.Barrier(clients)
    answers: list[tuple[list[float], Any]] = []
    failures: list[str] = []
    lock = threading.Lock()

    def client(i: int) -> None:
        rng = np.random.default_rng(i)
        try:
            barrier.wait(timeout=60)
            conn = http.client.HTTPConnection("127.0.0.1", http_server, timeout=60)
            for _ in range(per_client):
                obs = [round(float(v), 3) for v in rng.uniform(0, 100, 5)]
                status, action = _post(conn, json.dumps(obs).encode())
                with lock:
                    answers.append((obs, action) if status == 200 else (obs, None))
            conn.close()
        except Exception as exc:  # a reset, a refusal or a dropped connection: what this test is about
            with lock:
                failures.append(f"client {i}: {type(exc).__name__}: {exc}")

    threads = [threading.Thread(target=client, args=(i,)) for i in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert not any(t.is_alive() for t in threads)
    assert failures == [] and len(answers) == clients * per_client
    for obs, action in answers:
        assert action == pytest.approx(_expected(obs), rel=1e-5, abs=1e-3)


@pytest.fixture
def quick_timeout_server(box_policy: Policy) -> Iterator[PolicyHTTPServer]:
    """An in-process server whose connections close after 0.3 s of silence."""
    server = PolicyHTTPServer(("127.0.0.1", 0), box_policy, connection_timeout=0.3)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    yield server
    server.shutdown()
    server.server_close()
    thread.join(timeout=30)


def test_idle_connections_are_closed(quick_timeout_server: PolicyHTTPServer) -> None:
    assert PolicyHTTPServer.request_queue_size >= 128 and 10 <= CONNECTION_TIMEOUT <= 30
    assert PolicyHTTPServer.connection_timeout == CONNECTION_TIMEOUT
    assert 5 <= REQUEST_TIMEOUT <= 30 and PolicyHTTPServer.request_timeout == REQUEST_TIMEOUT
    port = quick_timeout_server.port
    with socket.create_connection(("127.0.0.1", port), timeout=30) as idle:
        assert idle.recv(1) == b""  # closed by the server (the client would wait 30 s and raise)
    with socket.create_connection(("127.0.0.1", port), timeout=30) as kept:  # idle after a request, too
        kept.sendall(f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
        reply = http.client.HTTPResponse(kept)
        reply.begin()
        assert reply.status == 200 and json.loads(reply.read())["obs_names"] == list(OBS_NAMES)
        assert kept.recv(1) == b""
    with socket.create_connection(("127.0.0.1", port), timeout=30) as stalled:  # a body that stops arriving
        stalled.sendall(f"POST / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Type: application/json\r\n"
                        "Content-Length: 100\r\n\r\n[22, 55".encode())
        reply = http.client.HTTPResponse(stalled)
        reply.begin()
        assert reply.status == 408 and "stopped arriving" in json.loads(reply.read())["error"]
        assert stalled.recv(1) == b""
    _good(http.client.HTTPConnection("127.0.0.1", port, timeout=30))  # and it still serves



def test_connections_over_the_cap_get_429_and_the_server_goes_on(box_policy: Policy) -> None:
    """Two idle connections fill a server capped at 2: a third is answered 429 (Retry-After) and closed at once;
    once one closes, requests are served again."""
    assert 16 <= MAX_CONNECTIONS <= 256
    server = PolicyHTTPServer(("127.0.0.1", 0), box_policy, connection_timeout=5.0, max_connections=2)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    try:
        idle = [socket.create_connection(("127.0.0.1", server.port), timeout=30) for _ in range(2)]
        deadline = time.monotonic() + 10
        while server.open_connections < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert server.open_connections == 2
        extra = http.client.HTTPConnection("127.0.0.1", server.port, timeout=30)
        extra.request("GET", "/")
        reply = extra.getresponse()
        assert reply.status == 429 and reply.getheader("Retry-After") == "1"
        assert "2 connections are open" in json.loads(reply.read())["error"]
        idle[0].close()
        while server.open_connections > 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        _good(http.client.HTTPConnection("127.0.0.1", server.port, timeout=30))
        assert server.refused == 1 and server.served == 1
        idle[1].close()
    finally:
        server.shutdown()
        server.server_close()
        thread.join(timeout=30)


@contextlib.contextmanager
def serving(policy: Policy, **kwargs: Any) -> Iterator[PolicyHTTPServer]:
    """An in-process :class:`PolicyHTTPServer` on 127.0.0.1 (a free port) with these keywords, serving in a thread
    until the block ends."""
    server = PolicyHTTPServer(("127.0.0.1", 0), policy, **kwargs)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    try:
        yield server
    finally:
        server.shutdown()
        server.server_close()
        thread.join(timeout=30)


def _until_closed(sock: socket.socket) -> bytes:
    """Everything the server sends until it closes the connection (a reset counts as closed)."""
    data = b""
    with contextlib.suppress(ConnectionError):
        while chunk := sock.recv(65536):
            data += chunk
    return data


def _trickle(port: int, burst: bytes, trickle: bytes, stop_at: float, results: dict[str, Any], name: str) -> None:
    """Connect to 127.0.0.1:``port``, send ``burst`` at once, then ``trickle`` one byte every 0.1 s (nothing more
    when it is empty), until the server closes the connection or ``stop_at`` (``time.monotonic()``): then
    ``results[name]`` is ``(closed by the server, what it sent)``."""
    with socket.create_connection(("127.0.0.1", port), timeout=30) as sock:
        sent, closed, got = 0, False, b""
        try:
            sock.sendall(burst)
            while time.monotonic() < stop_at and not closed:
                if select.select([sock], [], [], 0.1)[0]:  # a reply (the burst's, or a 408) or the close
                    chunk = sock.recv(65536)
                    got += chunk
                    closed = not chunk
                elif sent < len(trickle):
                    sock.sendall(trickle[sent : sent + 1])
                    sent += 1
        except ConnectionError:  # a reset (after the reply, which is read first): the server closed the connection
            closed = True
        results[name] = (closed, got)


def test_trickling_connections_are_dropped_at_the_request_deadline(box_policy: Policy) -> None:
    """Repro 8: connections that send a byte now and then (or nothing) fill every slot of a server capped at 5; each
    is dropped when its request is not in by the 1 s deadline (408 when part of one came; a silent close when idle),
    so a normal client that polls (getting 429 while they hold the slots) is served soon after, not when they stop.
    The silence limit (30 s) plays no part: every trickler sends a byte every 0.1 s."""
    with serving(box_policy, max_connections=5, request_timeout=1.0, connection_timeout=30.0) as server:
        port = server.port
        host = f"Host: 127.0.0.1:{port}\r\n".encode()
        slow = b"a" * 300  # 30 s of bytes at 0.1 s each: the tricklers outlast the client's wait below
        cases = {
            "idle": (b"", b""),
            "request line": (b"", b"GET /" + slow),
            "headers": (b"", b"GET / HTTP/1.1\r\n" + host + b"X-Slow: " + slow),
            "body": (b"POST / HTTP/1.1\r\n" + host + b"Content-Type: application/json\r\nContent-Length: 300\r\n\r\n",
                     b" " * 300),
            "kept alive, idle after a request": (b"GET / HTTP/1.1\r\n" + host + b"\r\n", b""),
        }
        stop_at = time.monotonic() + 30
        results: dict[str, Any] = {}
        threads = [threading.Thread(target=_trickle, args=(port, burst, trickle, stop_at, results, name))
                   for name, (burst, trickle) in cases.items()]
        for t in threads:
            t.start()
        wait_until = time.monotonic() + 10
        while server.open_connections < len(cases) and time.monotonic() < wait_until:
            time.sleep(0.01)
        statuses: list[int | str] = []
        while time.monotonic() < stop_at - 15:  # 15 s: well before the tricklers would stop by themselves
            client = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
            try:
                client.request("GET", "/")
                reply = client.getresponse()
                info = json.loads(reply.read())
                statuses.append(reply.status)
            except ConnectionError as exc:  # a 429's close can reset a request still being sent: retry as after one
                statuses.append(type(exc).__name__)
            client.close()
            if statuses[-1] == 200:
                break
            time.sleep(0.1)
        for t in threads:
            t.join(timeout=60)
        assert not any(t.is_alive() for t in threads)
        assert statuses[-1] == 200 and info["obs_names"] == list(OBS_NAMES), statuses[-5:]
        assert all(status == 429 or isinstance(status, str) for status in statuses[:-1]), statuses
        assert set(results) == set(cases)
        for name in ("request line", "headers", "body"):
            closed, got = results[name]
            assert closed and got.split(b"\r\n")[0].split(b" ")[1] == b"408", (name, got[:200])
            assert b"did not arrive in full within 1 s" in got, (name, got[-200:])
        assert results["idle"] == (True, b"")
        closed, got = results["kept alive, idle after a request"]
        assert closed and got.count(b"HTTP/1.1 ") == 1 and got.startswith(b"HTTP/1.1 200 OK"), got[:200]
        client = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
        _good(client)  # and it goes on serving
        client.close()


def test_a_pipelined_request_that_came_in_time_is_served(box_policy: Policy) -> None:
    """The deadline is per request: requests that arrived together are all answered (the connection is not dropped
    because the first one used up time), and a bad timeout is refused at construction."""
    with serving(box_policy, request_timeout=1.0) as server:
        obs = json.dumps(GOOD[0]).encode()
        one = (f"POST /act HTTP/1.1\r\nHost: 127.0.0.1:{server.port}\r\nContent-Type: application/json\r\n"
               f"Content-Length: {len(obs)}\r\n\r\n").encode() + obs
        with socket.create_connection(("127.0.0.1", server.port), timeout=30) as sock:
            sock.sendall(one * 3)
            sock.shutdown(socket.SHUT_WR)  # then the end of the stream: the server closes after the third
            got = _until_closed(sock)
        assert got.count(b"HTTP/1.1 200 OK") == 3 and b"408" not in got
    for bad in (0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="request_timeout must be a positive number of seconds"):
            bind(("127.0.0.1", 0), box_policy, request_timeout=bad)


# -- corrupt model and sidecar files --------------------------------------------------------------------------------

def _cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """``python -m sbagents.serve ARGV`` in this process, through the same runner: (exit status, stderr)."""
    from sbagents.cli_common import run
    from sbagents.serve import main

    with pytest.raises(SystemExit) as stopped:
        run("python -m sbagents.serve", lambda: main(argv))
    code = stopped.value.code
    return code if isinstance(code, int) else -1, capsys.readouterr().err


def _odd_model(path: Path, elem: int, in_shape: list[Any], out_shape: list[Any]) -> Path:
    """A valid ONNX graph that is not a policy serve can run (``Identity`` of a tensor of type ``elem``)."""
    return _save([helper.make_node("Identity", ["obs"], ["action"])],
                 [helper.make_tensor_value_info("obs", elem, in_shape)],
                 [helper.make_tensor_value_info("action", elem, out_shape)], [], path)


def _corrupt_cases(folder: Path, models: Models) -> list[tuple[str, Path, list[str], str]]:
    """(what, model file, extra arguments, a part of the one-line error)."""
    onnx_bytes = models.box.read_bytes()
    meta = json.loads((models.box.parent / "policy.json").read_text())
    cases: list[tuple[str, Path, list[str], str]] = []

    def case(what: str, model: bytes | None = None, sidecar: bytes | None = None, reason: str = "") -> None:
        d = folder / str(len(cases))
        d.mkdir(parents=True)
        (d / "policy.onnx").write_bytes(onnx_bytes if model is None else model)
        if sidecar is not None:
            (d / "policy.json").write_bytes(sidecar)
        cases.append((what, d / "policy.onnx", [], reason))

    case("empty policy.onnx", model=b"", reason="invalid ONNX model")
    case("truncated policy.onnx", model=onnx_bytes[: len(onnx_bytes) // 2], reason="invalid ONNX model")
    case("garbage policy.onnx", model=bytes(range(256)) * 8, reason="invalid ONNX model")
    case("malformed sidecar", sidecar=b'{"obs_names": [', reason="not JSON")
    case("binary sidecar", sidecar=b"\x00\xff\xfe\x80" * 50, reason="not UTF-8 text")
    case("sidecar is a JSON list", sidecar=b"[1, 2]", reason="a JSON list where an object")
    case("sidecar without keys", sidecar=b"{}", reason="no obs_names or action_names")
    case("sidecar without action_names", sidecar=json.dumps({"obs_names": OBS_NAMES}).encode(),
         reason="no action_names")
    case("obs_names not a list", sidecar=json.dumps({**meta, "obs_names": 5}).encode(), reason="obs_names must be")
    case("obs_names a string", sidecar=json.dumps({**meta, "obs_names": "abcde"}).encode(), reason="obs_names must")
    case("obs_names numbers", sidecar=json.dumps({**meta, "obs_names": [1, 2, 3, 4, 5]}).encode(),
         reason="obs_names must be")
    case("duplicate names", sidecar=json.dumps({**meta, "action_names": ["a", "a"]}).encode(),
         reason="action_names must be a list of distinct")
    case("too few names", sidecar=json.dumps({**meta, "obs_names": ["a", "b"]}).encode(),
         reason="obs_names has 2 names; the model has 5 observation values")
    case("deeply nested sidecar", sidecar=b"[" * 100_000, reason="not JSON")
    case("a 5000-digit integer in the sidecar", sidecar=b'{"n": ' + b"9" * 5000 + b"}", reason="not JSON")
    odd = folder / "odd"
    odd.mkdir()
    cases.append(("float64 model", _odd_model(odd / "f64.onnx", TensorProto.DOUBLE, ["b", 5], ["b", 5]), [],
                  "expected one float32 or int64 input"))
    cases.append(("dynamic feature size", _odd_model(odd / "dyn.onnx", TensorProto.FLOAT, ["b", "n"], ["b", "n"]),
                  [], "shapes must be static"))
    cases.append(("a folder for a model", folder, [], "model file not found"))
    cases.append(("a missing --meta", models.box, ["--meta", str(folder / "nowhere.json")], "sidecar not found"))
    cases.append(("--allow-any-host without --http", models.box, ["--allow-any-host"], "is for --http"))
    cases.append(("a --csv in a missing folder, over HTTP", models.box,
                  ["--http", "127.0.0.1:0", "--csv", str(folder / "nowhere" / "log.csv")], "cannot use"))
    return cases


def test_corrupt_model_and_sidecar_are_one_line_exit_2(models: Models, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    for what, model, extra, reason in _corrupt_cases(tmp_path, models):
        code, err = _cli(["--model", str(model), *extra], capsys)
        assert code == 2 and len(err.strip().splitlines()) == 1, (what, err)
        assert err.startswith("python -m sbagents.serve: error: ") and reason in err, (what, err)
        assert "Traceback" not in err and len(err) < 600, what


def test_corrupt_sidecar_in_a_real_process(models: Models, tmp_path: Path) -> None:
    (tmp_path / "policy.onnx").write_bytes(models.box.read_bytes())
    (tmp_path / "policy.json").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    done = subprocess.run(serve_command("--model", str(tmp_path / "policy.onnx")), input="[1, 2, 3, 4, 5]\n",
                          capture_output=True, text=True, env=_env(), timeout=60)
    assert done.returncode == 2 and done.stdout == "" and len(done.stderr.strip().splitlines()) == 1
    assert f"invalid sidecar {tmp_path / 'policy.json'}: not UTF-8 text" in done.stderr


def test_a_discrete_sidecar_range_is_checked(models: Models, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "policy.onnx").write_bytes(models.discrete.read_bytes())
    for space in ({"type": "discrete", "n": "25"}, {"type": "discrete", "n": 0}, {"type": "discrete", "n": True}):
        (tmp_path / "policy.json").write_text(json.dumps({"obs_names": ["cell"], "action_names": ["move"],
                                                          "observation_space": space}))
        code, err = _cli(["--model", str(tmp_path / "policy.onnx")], capsys)
        assert code == 2 and "observation_space n and start must be integers" in err, space


# -- property-based: the request parser ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def discrete_policy(models: Models) -> Policy:
    return Policy(models.discrete)


def _no_constant(name: str) -> float:
    raise AssertionError(f"a reply carried {name}")


def _check(policy: Policy, data: str | bytes) -> None:
    """``parse`` raises nothing but :class:`ServeError` (else gives ``obs_dim`` finite float32 numbers), and
    ``decide`` gives one reply of valid JSON: the action when it parsed and the policy's output is finite, else
    ``{"error": ...}``."""
    try:
        obs = policy.parse(data)
    except ServeError as exc:
        parsed = False
        assert str(exc) and "\n" not in str(exc) and len(str(exc)) < 600
    else:
        parsed = True
        assert len(obs) == policy.obs_dim
        assert all(isinstance(v, float) and math.isfinite(v) and abs(v) <= FLOAT32_MAX for v in obs)
    with DecisionLog(policy, None) as log:
        ok, reply = decide(policy, data, log)
    assert "\n" not in reply
    value = json.loads(reply, parse_constant=_no_constant)
    if ok:
        assert parsed
        if policy.discrete_action:
            assert isinstance(value, int) and not isinstance(value, bool)
        else:
            assert isinstance(value, list) and len(value) == policy.act_dim
            assert all(isinstance(v, float) and math.isfinite(v) for v in value)
    else:
        assert isinstance(value, dict) and list(value) == ["error"] and isinstance(value["error"], str)


if given is not None:
    NUMBERS = st.one_of(st.integers(), st.integers(min_value=-(10**500), max_value=10**500), st.floats(),
                        st.floats(width=32), st.sampled_from([3e38, 3.5e38, 1e308, -0.0, 2**63, -(2**63) - 1, 24]))
    JSON_VALUES = st.recursive(
        st.none() | st.booleans() | NUMBERS | st.text(max_size=10),
        lambda inner: st.lists(inner, max_size=6) | st.dictionaries(st.text(max_size=12), inner, max_size=6),
        max_leaves=25,
    )
    #: near misses of a valid observation: lists of about the right length, objects with about the right keys
    OBSERVATION_LIKE = st.one_of(
        st.lists(st.one_of(NUMBERS, st.booleans(), st.none(), st.text(max_size=3)), min_size=0, max_size=6),
        st.dictionaries(st.sampled_from([*OBS_NAMES, "Humidity", "cell"]), NUMBERS, min_size=3, max_size=6),
        NUMBERS,
    )
    TEXT = st.one_of(
        st.text(max_size=300),
        st.text(st.characters(exclude_categories=()), max_size=50),  # lone surrogates too
        st.binary(max_size=300),
        st.text(alphabet='[]{}",:-+.eE0123456789 \tNaInfity\\u', max_size=300),
    )
    FUZZ = settings(derandomize=True, max_examples=300, deadline=None, database=None,
                    suppress_health_check=[HealthCheck.too_slow])

    @FUZZ
    @given(data=TEXT)
    def test_fuzz_any_text_is_an_action_or_an_error_reply(box_policy: Policy, discrete_policy: Policy,
                                                           data: str | bytes) -> None:
        for policy in (box_policy, discrete_policy):
            _check(policy, data)

    @FUZZ
    @given(value=st.one_of(JSON_VALUES, OBSERVATION_LIKE), as_bytes=st.booleans())
    def test_fuzz_any_json_is_an_action_or_an_error_reply(box_policy: Policy, discrete_policy: Policy, value: Any,
                                                          as_bytes: bool) -> None:
        text = json.dumps(value)  # NaN and Infinity come out as those literals
        for policy in (box_policy, discrete_policy):
            _check(policy, text.encode() if as_bytes else text)

    @FUZZ
    @given(lines=st.lists(st.binary(max_size=20).map(lambda b: b.replace(b"\n", b"")), max_size=10),
           newline_at_end=st.booleans())
    def test_fuzz_every_line_gets_exactly_one_reply(box_policy: Policy, lines: list[bytes],
                                                    newline_at_end: bool) -> None:
        data = b"\n".join(lines) + (b"\n" if newline_at_end and lines else b"")
        parts = data.split(b"\n")[: -1 if data.endswith(b"\n") else None] if data else []
        assert list(read_lines(io.BytesIO(data), limit=8)) == [p if len(p) <= 8 else None for p in parts]
        out = io.StringIO()
        served, errors = serve(box_policy, io.BytesIO(data), out)
        replies = out.getvalue().splitlines()
        assert served + errors == len(parts) == len(replies)
        assert all(isinstance(json.loads(r), list | dict) for r in replies)
else:
    def test_fuzz_needs_hypothesis() -> None:
        pytest.skip("hypothesis is not installed (it is in the test extra: pip install -e '.[test]')")
