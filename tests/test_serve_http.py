"""``python -m sbagents.serve --http``: the torch-free decision loop over HTTP on loopback."""

from __future__ import annotations

import csv
import http.client
import json
import os
import re
import select
import signal
import socket
import subprocess
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch
from cli_helpers import serve_command
from stable_baselines3 import TD3
from stable_baselines3.common.env_util import make_vec_env

import sbagents  # noqa: F401 (registers the env ids)
from sbagents.deploy.exporting import ExportChecks, export_run
from sbagents.deploy.http_serving import is_loopback, parse_address

torch.set_num_threads(1)
ROOT = Path(__file__).resolve().parents[1]
OBS_NAMES = ("Temperature", "Light_Level", "Time", "Preferred_Temp", "Preferred_Light")
#: bodies the line protocol also refuses (bad JSON, wrong length, unknown key, non-number, not finite)
MALFORMED = ["{not json", json.dumps([22.0, 55.0, 3.0, 24.0]),
             json.dumps({**dict.fromkeys(OBS_NAMES, 1.0), "Humidity": 3}), json.dumps([22.0, "hot", 3.0, 24.0, 70.0]),
             "[22.0, NaN, 3.0, 24.0, 70.0]"]


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, TD3]:
    out = tmp_path_factory.mktemp("export")
    model = TD3("MlpPolicy", make_vec_env("sbagents/SmartHome-v0", n_envs=1, seed=0), seed=0, device="cpu",
                buffer_size=1000, policy_kwargs={"net_arch": [16, 16]})
    export_run(model, out, "sbagents/SmartHome-v0", checks=ExportChecks(n_observations=20, latency_n=5))
    return out / "policy.onnx", model


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT)}


@pytest.fixture
def server(exported: tuple[Path, TD3], tmp_path: Path) -> Iterator[tuple[subprocess.Popen[str], int, Path]]:
    """A running ``serve --http 127.0.0.1:0`` (torch blocked) with a CSV log; its port from its first line."""
    log = tmp_path / "decisions.csv"
    proc = subprocess.Popen(serve_command("--model", str(exported[0]), "--http", "127.0.0.1:0", "--csv", str(log)),
                            stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=_env())
    assert proc.stderr is not None
    ready, _, _ = select.select([proc.stderr], [], [], 60)
    line = proc.stderr.readline() if ready else ""
    found = re.search(r"http://127\.0\.0\.1:(\d+)/", line)
    assert found, line
    yield proc, int(found.group(1)), log
    if proc.poll() is None:
        proc.kill()
        proc.wait()


def _request(conn: http.client.HTTPConnection, method: str, path: str, body: str | None = None
             ) -> tuple[int, object]:
    conn.request(method, path, body=body, headers={"Content-Type": "application/json"})
    reply = conn.getresponse()
    return reply.status, json.loads(reply.read())


def test_http_serves_the_same_actions_errors_and_log_as_the_line_protocol(
    server: tuple[subprocess.Popen[str], int, Path], exported: tuple[Path, TD3], tmp_path: Path
) -> None:
    proc, port, log = server
    model = exported[1]
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)  # one kept-alive connection throughout
    status, info = _request(conn, "GET", "/")
    assert status == 200 and info == {"obs_names": list(OBS_NAMES), "action_names": ["Action_Temp", "Action_Light"],
                                      "discrete_action": False}
    good = [[22.0, 55.0, 3.0, 24.0, 70.0], [19.5, 80.0, 23.0, 21.0, 52.0]]
    named = dict(zip(OBS_NAMES, [25.0, 10.0, 12.0, 20.0, 60.0], strict=True))
    actions = []
    for path, body in (("/", json.dumps(good[0])), ("/act", json.dumps(named)), ("/", json.dumps(good[1]))):
        status, action = _request(conn, "POST", path, body)
        assert status == 200
        actions.append(action)
    obs = np.array([good[0], list(named.values()), good[1]])
    np.testing.assert_allclose(np.array(actions), model.predict(obs, deterministic=True)[0], atol=1e-4)

    line_replies = subprocess.run(serve_command("--model", str(exported[0])), input="\n".join(MALFORMED) + "\n",
                                  capture_output=True, text=True, env=_env(), timeout=60).stdout.splitlines()
    for body, line_reply in zip(MALFORMED, line_replies, strict=True):
        status, error = _request(conn, "POST", "/", body)
        assert status == 400 and error == json.loads(line_reply) and "error" in error  # type: ignore[operator]

    assert _request(conn, "POST", "/nowhere", "[1]")[0] == 404
    assert _request(conn, "GET", "/nowhere")[0] == 404
    status, error = _request(conn, "PUT", "/", "[1]")
    assert status == 405 and "POST an observation" in error["error"]  # type: ignore[index]
    big = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    assert _request(big, "POST", "/", "[" + "1.0, " * 20_000 + "1.0]")[0] == 413

    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0 and "stopped: 3 decisions, 5 malformed requests, 4 refused" in stderr
    rows = list(csv.reader(log.open()))
    assert rows[0] == ["timestamp", *OBS_NAMES, "Action_Temp", "Action_Light"] and len(rows) == 4
    assert [float(v) for v in rows[2][1:6]] == list(named.values())
    assert [float(v) for v in rows[3][6:]] == pytest.approx(actions[2], abs=1e-6)


def test_port_in_use_and_bad_addresses_are_one_line(exported: tuple[Path, TD3]) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = subprocess.run(serve_command("--model", str(exported[0]), "--http", f"127.0.0.1:{port}"),
                              capture_output=True, text=True, env=_env(), timeout=60)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1
    assert f"port {port} is in use on 127.0.0.1" in done.stderr
    for bad in ("127.0.0.1:http", "99999", "127.0.0.1:", "127.0.0.1:\u0668\u0660"):  # Arabic-Indic digits too
        done = subprocess.run(serve_command("--model", str(exported[0]), "--http", bad), capture_output=True, text=True,
                              env=_env(), timeout=60)
        assert done.returncode == 2 and "expected HOST:PORT or PORT" in done.stderr, bad


def test_address_parsing_and_loopback() -> None:
    assert parse_address("8000") == ("127.0.0.1", 8000)
    assert parse_address("0.0.0.0:80") == ("0.0.0.0", 80)
    assert parse_address("[::1]:8080") == ("::1", 8080)
    assert all(is_loopback(h) for h in ("localhost", "127.0.0.1", "127.1.2.3", "::1"))
    assert not any(is_loopback(h) for h in ("0.0.0.0", "192.168.1.10", "::", "hub.local"))


def test_benchmark_section_is_its_saved_results() -> None:
    """BENCHMARKS.md's serve-latency section is what ``benchmarks.speed.serve_latency`` makes of its saved results, and
    those back the claim made of them: 50 clients connecting at once lost no request."""
    from benchmarks.speed import serve_latency

    saved = json.loads((ROOT / "benchmarks" / "results" / "serve_latency.json").read_text())
    text = (ROOT / "BENCHMARKS.md").read_text()
    start, end = "<!-- serve-latency:start -->\n", "\n<!-- serve-latency:end -->"
    section = text[text.index(start) + len(start): text.index(end)]
    assert serve_latency.markdown(saved) == section
    at_once = saved["bursts"]["at_once"]
    assert at_once["clients"] == 50 and at_once["requests"] == at_once["answered"] == 1000 and at_once["lost"] == 0
