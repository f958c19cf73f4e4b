"""Seeded fuzz of ``python -m sbagents.serve``: valid HTTP requests and JSON lines, mutated byte by byte.

Every mutated request must get an answer or an error reply (never a 5xx, never a dropped connection without a reply
for a request that has any content), and the server must still answer a valid request afterwards. The loops are
:func:`fuzz_http` and :func:`fuzz_lines` (a case count and a seed); the tests run 200 cases of each, and a longer run
calls them with more::

    python tests/test_serve_fuzz.py --cases 20000 --seed 7
"""

from __future__ import annotations

import argparse
import io
import json
import math
import random
import socket
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest
from cli_helpers import serve_command
from test_serve_hostile import GOOD, OBS_NAMES, _box_model, _env, _expected, serving

from sbagents.deploy.http_serving import PolicyHTTPServer
from sbagents.deploy.serving import Policy, read_lines, serve

#: Byte strings a mutation inserts: protocol punctuation, bytes that are not UTF-8, numbers at the edges, headers that
#: change how a request is read, JSON that is valid but not an observation.
TOKENS = (b"\r\n", b"\n", b"\r", b" ", b"\t", b":", b"\x00", b"\xff", b"\x80", b"\xc3", b"0", b"-1", b"9" * 20, b"[",
          b"]", b"{", b"}", b'"', b",", b"NaN", b"1e999", b"true", b"null", b"Content-Length: 99999999\r\n",
          b"Content-Length: 5\r\n", b"Transfer-Encoding: chunked\r\n", b"Expect: 100-continue\r\n",
          b"Host: evil.example\r\n", b"Connection: close\r\n", b"HTTP/2.0", b"HEAD", b"/act", b"/../", b"%00",
          b"\r\n\r\n", json.dumps(dict.fromkeys(OBS_NAMES, 1.0)).encode())
#: Statuses a fuzzed request may get: an answer, an error reply, or 100 before the body (``Expect: 100-continue``).
ALLOWED_STATUSES = {100, 200, 400, 404, 405, 408, 411, 413, 414, 415, 421, 429, 431}


def mutate(data: bytes, rng: random.Random, others: Sequence[bytes] = ()) -> bytes:
    """``data`` after 1-4 random edits (flip a bit, insert or overwrite a byte, delete or repeat a run, insert a
    :data:`TOKENS` entry, splice in the tail of one of ``others``, truncate); never empty."""
    out = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(8)
        pos = rng.randint(0, len(out))
        if op == 0 and out:
            out[pos % len(out)] ^= 1 << rng.randrange(8)
        elif op == 1:
            out[pos:pos] = bytes([rng.randrange(256)])
        elif op == 2 and out:
            out[pos % len(out)] = rng.choice(b"\r\n :\x00\xff0123456789[]{},\"")
        elif op == 3:
            del out[pos : pos + rng.randint(1, 16)]
        elif op == 4:
            run = bytes(out[pos : pos + rng.randint(1, 16)])
            out[pos:pos] = run * rng.randint(1, 3)
        elif op == 5:
            out[pos:pos] = rng.choice(TOKENS)
        elif op == 6 and others:
            other = rng.choice(others)
            out[pos:] = other[rng.randint(0, len(other)) :]
        elif op == 7:
            del out[pos:]
    return bytes(out) or bytes([rng.randrange(256)])


def http_seeds(port: int) -> list[bytes]:
    """Valid requests to a server of the SmartHome-shaped Box policy on 127.0.0.1:``port``."""
    host = f"Host: 127.0.0.1:{port}\r\n".encode()

    def post(path: str, body: bytes, extra: bytes = b"") -> bytes:
        return (f"POST {path} HTTP/1.1\r\n".encode() + host + b"Content-Type: application/json\r\n" + extra
                + f"Content-Length: {len(body)}\r\n\r\n".encode() + body)

    as_list, as_object = json.dumps(GOOD[0]).encode(), json.dumps(dict(zip(OBS_NAMES, GOOD[1], strict=True))).encode()
    return [post("/", as_list), post("/act", as_object), post("/", as_list, b"Connection: keep-alive\r\n"),
            b"GET / HTTP/1.1\r\n" + host + b"\r\n", b"GET /policy HTTP/1.1\r\n" + host + b"Accept: */*\r\n\r\n",
            post("/", as_list) + b"GET / HTTP/1.1\r\n" + host + b"\r\n"]  # two pipelined requests


def parse_replies(data: bytes) -> list[tuple[int, dict[str, str], bytes | None]]:
    """The HTTP replies in ``data`` (all a connection sent): ``(status, headers in lower case, body)``; the body
    None when the reply says it has one but nothing follows (a reply to HEAD).

    :raises ValueError: ``data`` is not a sequence of complete replies.
    """
    replies: list[tuple[int, dict[str, str], bytes | None]] = []
    while data:
        head, sep, data = data.partition(b"\r\n\r\n")
        if not sep:
            raise ValueError(f"an incomplete reply head: {head[:200]!r}")
        lines = head.decode("latin-1").split("\r\n")
        version, status, _ = (lines[0] + " ").split(" ", 2)
        if not version.startswith("HTTP/1.") or not status.isdigit():
            raise ValueError(f"not a status line: {lines[0][:200]!r}")
        headers = {k.strip().lower(): v.strip() for k, _, v in (line.partition(":") for line in lines[1:])}
        length = int(headers.get("content-length", "0"))
        body: bytes | None = None
        if data or not length:
            if len(data) < length:
                raise ValueError(f"a body of {len(data)} bytes where Content-Length says {length}")
            body, data = data[:length], data[length:]
        replies.append((int(status), headers, body))
    return replies


def _exchange(port: int, request: bytes) -> bytes:
    """Send ``request``, then the end of the stream, and read until the server closes the connection."""
    with socket.create_connection(("127.0.0.1", port), timeout=30) as sock:
        got = b""
        try:
            sock.sendall(request)
            sock.shutdown(socket.SHUT_WR)
            while chunk := sock.recv(65536):
                got += chunk
        except ConnectionError:  # a reset after the reply (the server closed with unread bytes): what came counts
            pass
        return got


def _blank(request: bytes) -> bool:
    """Whether ``request`` is only empty lines (the server skips those before a request line, then sees the end)."""
    return not str(request, "latin-1").split()


def check_reply(status: int, headers: dict[str, str], body: bytes | None, request: bytes) -> str:
    """Check one reply to a fuzzed ``request`` and name its outcome (``"200 action"``, ``"400 error"``, ...).

    :raises AssertionError: a status outside :data:`ALLOWED_STATUSES` (a 5xx above all) or a reply that is not the
        server's JSON.
    """
    assert status in ALLOWED_STATUSES, (status, body, request[:300])
    if status == 100:
        return "100 continue"
    assert headers.get("content-type") == "application/json", (status, headers, request[:300])
    if body is None:  # a reply to HEAD carries no body
        assert b"HEAD" in request, (status, request[:300])
        return f"{status} (HEAD, no body)"
    value = json.loads(body)
    if status != 200:
        assert isinstance(value, dict) and list(value) == ["error"] and isinstance(value["error"], str), body
        assert len(value["error"]) < 600, body
        return f"{status} error"
    if isinstance(value, dict):
        assert value["obs_names"] == list(OBS_NAMES), value
        return "200 policy info"
    assert isinstance(value, list) and len(value) == 2 and all(isinstance(v, float) and math.isfinite(v)
                                                             for v in value), value
    return "200 action"


def fuzz_http(port: int, cases: int = 200, seed: int = 0) -> Counter[str]:
    """Send ``cases`` mutated requests (:func:`mutate` of :func:`http_seeds`, ``random.Random(seed)``) to the
    server on 127.0.0.1:``port``, one connection each, and check every reply (:func:`check_reply`).

    :return: how many replies had each outcome, plus ``"connections"`` and ``"no reply (blank lines only)"``.
    :raises AssertionError: a bad reply, or no reply to a request with content.
    """
    rng = random.Random(seed)
    seeds = http_seeds(port)
    outcomes: Counter[str] = Counter()
    for _ in range(cases):
        request = mutate(rng.choice(seeds), rng, seeds)
        data = _exchange(port, request)
        try:
            replies = parse_replies(data)
        except ValueError as exc:
            raise AssertionError(f"{exc}; request {request[:300]!r}") from None
        outcomes["connections"] += 1
        if not replies:
            assert _blank(request), f"no reply to {request[:300]!r}"
            outcomes["no reply (blank lines only)"] += 1
        for status, headers, body in replies:
            outcomes[check_reply(status, headers, body, request)] += 1
    return outcomes


def line_seeds() -> list[bytes]:
    """Valid observation lines of the SmartHome-shaped Box policy: lists and objects keyed by its names."""
    return [json.dumps(GOOD[0]).encode(), json.dumps(GOOD[1]).encode(),
            json.dumps(dict(zip(OBS_NAMES, GOOD[0], strict=True))).encode(), b"[1, 2, 3, 4, 5]",
            b'{"Preferred_Light": 70, "Time": 3.5e0, "Temperature": -22, "Light_Level": 55, "Preferred_Temp": 24}']


def fuzz_lines(policy: Policy, cases: int = 200, seed: int = 0) -> tuple[bytes, str, Counter[str]]:
    """Serve ``cases`` mutated lines (:func:`mutate` of :func:`line_seeds`, ``random.Random(seed)``, without the
    line breaks a mutation inserts), then one valid line, through the line protocol in this process and check that
    every line got one reply: the action (a list of finite floats) or ``{"error": ...}``.

    :return: ``(the input, the output, how many replies of each kind)``.
    :raises AssertionError: a missing, extra or malformed reply.
    """
    rng = random.Random(seed)
    seeds = line_seeds()
    data = b"".join(mutate(rng.choice(seeds), rng, seeds).replace(b"\n", b"") + b"\n" for _ in range(cases))
    data += json.dumps(GOOD[0]).encode() + b"\n"  # still served at the end
    out = io.StringIO()
    served, errors = serve(policy, io.BytesIO(data), out)
    replies = out.getvalue().splitlines()
    assert served + errors == len(replies) == len(list(read_lines(io.BytesIO(data), policy.max_request_bytes)))
    assert len(replies) == cases + 1
    outcomes: Counter[str] = Counter()
    for reply in replies:
        value = json.loads(reply)
        if isinstance(value, dict):
            assert list(value) == ["error"] and isinstance(value["error"], str) and len(value["error"]) < 600, value
            outcomes["error"] += 1
        else:
            assert isinstance(value, list) and len(value) == policy.act_dim, value
            assert all(isinstance(v, float) and math.isfinite(v) for v in value), value
            outcomes["action"] += 1
    assert json.loads(replies[-1]) == pytest.approx(_expected(GOOD[0]), abs=1e-4)
    return data, out.getvalue(), outcomes


def _good_request(port: int) -> list[float]:
    """POST one good observation on a fresh connection; its action."""
    body = json.dumps(GOOD[1]).encode()
    replies = parse_replies(_exchange(port, (f"POST / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Type: "
                                             f"application/json\r\nContent-Length: {len(body)}\r\n\r\n").encode()
                                      + body))
    assert len(replies) == 1 and replies[0][0] == 200 and replies[0][2] is not None, replies
    action: list[float] = json.loads(replies[0][2])
    return action


@pytest.fixture(scope="module")
def fuzz_policy(tmp_path_factory: pytest.TempPathFactory) -> Policy:
    return Policy(_box_model(tmp_path_factory.mktemp("fuzz") / "box"))


def test_fuzzed_http_requests_get_answers_or_error_replies(fuzz_policy: Policy,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    """200 mutated requests, each on its own connection: every one with content gets replies, none a 5xx, each the
    server's JSON; nothing is printed (an exception in a handler would be); a valid request is answered after."""
    with serving(fuzz_policy, request_timeout=5.0) as server:
        outcomes = fuzz_http(server.port, cases=200, seed=0)
        assert outcomes["connections"] == 200
        assert outcomes["200 action"] > 0 and outcomes["400 error"] > 0  # the mutations reach the policy and miss it
        assert _good_request(server.port) == pytest.approx(_expected(GOOD[1]), abs=1e-4)
        assert _all_closed(server)  # no connection thread is left waiting
    assert capsys.readouterr().err == ""


def _all_closed(server: PolicyHTTPServer, wait: float = 10.0) -> bool:
    """Whether every connection thread of ``server`` has ended (or does within ``wait`` seconds)."""
    give_up = time.monotonic() + wait
    while server.open_connections and time.monotonic() < give_up:
        time.sleep(0.01)
    return server.open_connections == 0


def test_fuzzed_lines_get_one_reply_each_in_the_real_server(fuzz_policy: Policy) -> None:
    """200 mutated observation lines: in this process every line gets one reply (the action or an error) and the
    valid line after them its action; the real torch-free ``python -m sbagents.serve`` gives the same output, exit
    status 0 and no stderr."""
    data, expected, outcomes = fuzz_lines(fuzz_policy, cases=200, seed=0)
    assert outcomes["action"] > 1 and outcomes["error"] > 0
    done = subprocess.run(serve_command("--model", str(fuzz_policy.path)), input=data, capture_output=True,
                          env=_env(), timeout=120)
    assert done.returncode == 0 and done.stderr == b"", done.stderr.decode(errors="replace")[-2000:]
    assert done.stdout.decode() == expected


def main(argv: Sequence[str] | None = None) -> int:
    """A longer run: ``--cases`` of each kind from ``--seed``, against an in-process server; prints the counts."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--cases", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        policy = Policy(_box_model(Path(folder) / "box"))
        with serving(policy, request_timeout=5.0) as server:
            http_outcomes = fuzz_http(server.port, args.cases, args.seed)
            assert _good_request(server.port) == pytest.approx(_expected(GOOD[1]), abs=1e-4)
        _, _, line_outcomes = fuzz_lines(policy, args.cases, args.seed)
    result: dict[str, Any] = {"cases": args.cases, "seed": args.seed, "http": dict(sorted(http_outcomes.items())),
                              "lines": dict(sorted(line_outcomes.items()))}
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
