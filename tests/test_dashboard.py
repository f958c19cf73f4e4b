"""sbagents.dashboard over HTTP (Flask's test client and the real CLI): the runs table, a run's curves and files,
decisions paging and filters, trust views, malformed files, path traversal, the token and bad input."""

from __future__ import annotations

import csv
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("flask")

from sbagents.dashboard.app import TOKEN_COOKIE, create_app  # noqa: E402
from sbagents.dashboard.folders import ServedFolders  # noqa: E402
from tests.cli_helpers import cli, default_sigint  # noqa: E402

RUN = "ddpg/sbagents_SmartHome-v0_1"
LOG_HEADER = ["env", "episode", "step", "temp", "light", "action_temp", "reward", "terminated", "truncated",
              "violation", "cost"]


def write_run(folder: Path, rel: str = RUN, episodes: int = 6, steps: int = 10, seed: int = 0) -> Path:
    """A run dir as ``train`` writes it, with a transparency log whose violations are known (every 7th row)."""
    run_dir = folder / rel
    (run_dir / "sbagents_SmartHome-v0").mkdir(parents=True)
    args = f"algo: ddpg\nenv: sbagents/SmartHome-v0\nseed: {seed}\n"
    (run_dir / "sbagents_SmartHome-v0" / "args.yml").write_text(args)
    (run_dir / "sbagents_SmartHome-v0" / "config.yml").write_text("policy: MlpPolicy\nlearning_rate: 0.001\n")
    (run_dir / "command.txt").write_text("python -m sbagents.train --algo ddpg --env sbagents/SmartHome-v0\n")
    (run_dir / "summary.json").write_text(json.dumps({
        "algo": "ddpg", "env": "sbagents/SmartHome-v0", "seed": seed, "n_timesteps": episodes * steps,
        "train_seconds": 1.5, "fps": 40.0, "interrupted": False,
        "eval": {"mean_return": -12.5, "std_return": 2.0, "success_rate": 0.5, "n_episodes": 2},
    }))
    rows = ["#" + json.dumps({"t_start": 1000.0, "env_id": "sbagents/SmartHome-v0"}), "r,l,t"]
    rows += [f"{-50 + 5 * i},{steps},{i + 1}.0" for i in range(episodes)]
    (run_dir / "0.monitor.csv").write_text("\n".join(rows) + "\n")
    np.savez(run_dir / "evaluations.npz", timesteps=np.array([20, 40, 60]),
             results=np.array([[-40.0, -30.0], [-20.0, -10.0], [-14.0, -11.0]]),
             ep_lengths=np.full((3, 2), steps), successes=np.array([[0, 0], [0, 1], [1, 0]]))
    with (run_dir / "transparency.csv").open("w", newline="") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(LOG_HEADER)
        row = 0
        for ep in range(episodes):
            for step in range(steps):
                bad = row % 7 == 3
                writer.writerow([0, ep, step, 20 + step / 10, 50, 0.1, -1.0 - step, step == steps - 1, False,
                                 "too_cold" if bad else "", 1.0 if bad else 0.0])
                row += 1
    (run_dir / "safety.json").write_text(json.dumps({
        "violations": {"too_cold": 9}, "total_violations": 9, "total_steps": 60, "violation_rate": 0.15,
        "episodes": 6, "ep_cost": {"mean": 1.5, "std": 0.5, "max": 2.0, "last_window_mean": 1.5, "window": 100},
        "cost_limit": None, "stopped": False, "stop_reason": None,
        "constraint": {"method": "lagrangian", "cost_limit": 1.0, "multiplier": 0.3, "last_ep_cost": 1.5,
                       "history": [{"timesteps": 30, "ep_cost": 2.0, "multiplier": 0.1},
                                   {"timesteps": 60, "ep_cost": 1.5, "multiplier": 0.3}]},
    }))
    (run_dir / "adversarial.csv").write_text(
        "timesteps,attack,eps,mean_return,std_return,success_rate,violations,episodes,mean_length,max_perturbation\n"
        "60,none,0.0,-12.0,1.0,0.5,0,2,10,0.0\n60,fgsm,0.1,-20.0,2.0,0.0,1,2,10,0.1\n"
        "60,fgsm,0.2,-30.0,3.0,0.0,2,2,10,0.2\n")
    (run_dir / "fairness.csv").write_text(
        "preferred_temp_low,preferred_temp_high,n,successes,success_rate,ci_low,ci_high\n"
        "20.0,23.0,4,3,0.75,0.3,0.95\n23.0,26.0,4,1,0.25,0.05,0.7\n")
    (run_dir / "videos").mkdir()
    (run_dir / "videos" / "clip.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(64))
    return run_dir


@pytest.fixture()
def logs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("SBAGENTS_CACHE_DIR", str(tmp_path / "cache"))
    folder = tmp_path / "logs"
    write_run(folder)
    return folder


@pytest.fixture()
def client(logs: Path):  # type: ignore[no-untyped-def]
    return create_app(ServedFolders.from_paths([logs])).test_client()


def test_runs_table_lists_runs_and_picks_up_new_ones(client, logs: Path) -> None:  # type: ignore[no-untyped-def]
    runs = client.get("/api/runs").get_json()["runs"]
    assert [r["id"] for r in runs] == [f"0/{RUN}"]
    row = runs[0]
    assert (row["algo"], row["env"], row["k"], row["seed"], row["steps"]) == ("ddpg", "sbagents/SmartHome-v0", 1, 0, 60)
    assert (row["status"], row["eval_return"], row["success_rate"], row["backend"]) == ("finished", -12.5, 0.5, "sb3")
    write_run(logs, "ppo/sbagents_SmartHome-v0_2", seed=7)
    ids = {r["id"] for r in client.get("/api/runs").get_json()["runs"]}
    assert ids == {f"0/{RUN}", "0/ppo/sbagents_SmartHome-v0_2"}
    page = client.get("/")
    assert page.status_code == 200 and b'data-page="runs"' in page.data
    assert "script-src" not in page.headers["Content-Security-Policy"]  # scripts fall back to default-src 'self'
    assert page.headers["Content-Security-Policy"].startswith("default-src 'self'")


def test_run_curves_settings_and_files(client) -> None:  # type: ignore[no-untyped-def]
    curves = client.get(f"/api/curves/0/{RUN}").get_json()
    assert curves["train"]["returns"] == [-50.0, -45.0, -40.0, -35.0, -30.0, -25.0]
    assert curves["train"]["timesteps"] == [10.0, 20.0, 30.0, 40.0, 50.0, 60.0]
    assert curves["eval"]["mean"] == [-35.0, -15.0, -12.5]
    assert curves["eval"]["std"] == [5.0, 5.0, 1.5]
    assert curves["eval"]["success"] == [0.0, 0.5, 0.5]
    settings = client.get(f"/api/settings/0/{RUN}").get_json()
    assert settings["command"].startswith("python -m sbagents.train")
    assert settings["config"]["learning_rate"] == 0.001 and settings["args"]["seed"] == 0
    assert settings["logs"] == ["transparency.csv"]
    assert [v["path"] for v in settings["files"]["videos"]] == ["videos/clip.mp4"]
    video = client.get(f"/file/0/{RUN}/videos/clip.mp4", headers={"Range": "bytes=0-3"})
    assert video.status_code == 206 and video.data == b"\x00\x00\x00\x18"
    for page in ("run", "decisions", "trust"):
        assert client.get(f"/{page}/0/{RUN}").status_code == 200


def test_decisions_paging_filters_and_episode(client) -> None:  # type: ignore[no-untyped-def]
    api = f"/api/decisions/0/{RUN}?log=transparency.csv"
    page = client.get(api + "&start=10&count=5").get_json()
    assert page["columns"] == LOG_HEADER and page["row_numbers"] == [10, 11, 12, 13, 14]
    assert page["total_rows"] == 60 and page["rows"][0][1:3] == ["1", "0"]
    tail = client.get(api + "&tail=1&count=3").get_json()
    assert tail["row_numbers"] == [57, 58, 59]
    violations = client.get(api + "&violations=1&count=100").get_json()
    assert violations["row_numbers"] == [i for i in range(60) if i % 7 == 3]
    assert all(r[-2] == "too_cold" for r in violations["rows"]) and violations["next_cursor"] is None
    first = client.get(api + "&violations=1&count=4").get_json()
    rest = client.get(api + f"&violations=1&count=100&cursor={first['next_cursor']}").get_json()
    assert first["row_numbers"] + rest["row_numbers"] == violations["row_numbers"]
    combined = client.get(api + "&episode=2&step_min=2&step_max=4&reward_max=-4").get_json()
    assert [r[1:3] for r in combined["rows"]] == [["2", "3"], ["2", "4"]]
    episode = client.get(f"/api/episode/0/{RUN}?log=transparency.csv&episode=4").get_json()
    assert [r[2] for r in episode["rows"]] == [str(s) for s in range(10)] and episode["video"] is None
    assert client.get(f"/api/decisions/0/{RUN}?log=summary.json").status_code == 404
    assert client.get(api + "&start=x").status_code == 400


def test_trust_views(client) -> None:  # type: ignore[no-untyped-def]
    trust = client.get(f"/api/trust/0/{RUN}").get_json()
    assert trust["safety"][0]["total_violations"] == 9
    assert [h["multiplier"] for h in trust["safety"][0]["constraint"]["history"]] == [0.1, 0.3]
    costs = trust["ep_cost"]
    assert costs["has_cost"] and costs["progress"] == 1.0
    expected = [sum(1.0 for s in range(10) if (ep * 10 + s) % 7 == 3) for ep in range(6)]
    assert costs["ep_cost"] == expected and costs["violations"] == [int(c) for c in expected]
    fgsm = trust["adversarial"]["curves"]["60"]["fgsm"]
    assert fgsm["eps"] == [0.0, 0.1, 0.2] and fgsm["mean_return"] == [-12.0, -20.0, -30.0]
    fair = trust["fairness"]
    assert fair["keys"] == ["preferred_temp"] and fair["metric"] == "success_rate"
    assert [b["value"] for b in fair["buckets"]] == [0.75, 0.25] and fair["buckets"][0]["ci"] == [0.3, 0.95]


def test_compare_curves(client, logs: Path) -> None:  # type: ignore[no-untyped-def]
    write_run(logs, "ddpg/sbagents_SmartHome-v0_2", seed=1)
    data = client.get(f"/api/compare?run=0/{RUN}&run=0/ddpg/sbagents_SmartHome-v0_2").get_json()
    assert [r["run"]["k"] for r in data["runs"]] == [1, 2]
    assert all(len(r["train"]["returns"]) == 6 for r in data["runs"])
    assert client.get("/api/compare?run=0/../secret").status_code == 404


def test_malformed_files_show_what_is_readable(client, logs: Path) -> None:  # type: ignore[no-untyped-def]
    run_dir = logs / RUN
    (run_dir / "summary.json").write_text('{"algo": "ddpg", "n_timest')
    with (run_dir / "0.monitor.csv").open("a") as fh:
        fh.write("oops,not,a,row\n-3,10")  # a malformed row and a row being written
    (run_dir / "evaluations.npz").write_bytes(b"PK\x03\x04 truncated")
    (run_dir / "fairness.csv").write_text("")
    runs = client.get("/api/runs").get_json()["runs"]
    assert runs[0]["status"] in ("running", "incomplete") and "summary.json" in " ".join(runs[0]["notes"])
    curves = client.get(f"/api/curves/0/{RUN}").get_json()
    assert len(curves["train"]["returns"]) == 6 and curves["eval"]["mean"] == []
    notes = " ".join(curves["notes"])
    assert "1 malformed row" in notes and "evaluations.npz could not be read" in notes
    assert client.get(f"/run/0/{RUN}").status_code == 200
    assert client.get(f"/api/trust/0/{RUN}").get_json()["fairness"] is None


def test_only_files_under_the_served_folders(client, logs: Path, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    secret = tmp_path / "secret.txt"
    secret.write_text("do not serve")
    (logs / "inside.txt").write_text("fine")
    (logs / RUN / "escape.csv").symlink_to(secret)
    (logs / "ppo").mkdir()
    (logs / "ppo" / "linked_1").symlink_to(tmp_path, target_is_directory=True)
    assert client.get("/file/0/inside.txt").data == b"fine"
    attempts = [
        "/file/0/../secret.txt", "/file/0/%2e%2e/secret.txt", "/file/0/ddpg/..%2f..%2fsecret.txt",
        f"/file/0/{RUN}/escape.csv", "/file/0/ppo/linked_1/secret.txt", "/file/0//etc/passwd", "/file/0/%2Fetc/passwd",
        "/file/1/inside.txt", "/file/0/ddpg\\..\\..\\secret.txt", f"/file/0/{RUN}", "/run/0/../..", "/run/0/ppo",
        f"/api/decisions/0/{RUN}?log=escape.csv", f"/api/decisions/0/{RUN}?log=../../secret.txt",
        f"/api/decisions/0/{RUN}?log=/etc/passwd", "/api/curves/0/ppo/linked_1",
    ]
    for url in attempts:
        response = client.get(url)
        assert response.status_code == 404, url
        assert b"do not serve" not in response.data
    assert all(r["id"] != "0/ppo/linked_1" for r in client.get("/api/runs").get_json()["runs"])
    assert client.post("/api/runs").status_code == 405


def test_token_is_checked_on_every_request(logs: Path) -> None:
    client = create_app(ServedFolders.from_paths([logs]), token="s3cret-token", check_host=False).test_client()
    for url in ("/", "/api/runs", f"/file/0/{RUN}/command.txt", "/static/dashboard.js"):
        assert client.get(url).status_code == 401, url
        assert client.get(url + "?token=wrong-token").status_code == 401, url
        assert client.get(url, headers={"Authorization": "Bearer s3cret-token"}).status_code == 200, url
    first = client.get("/?token=s3cret-token")
    assert first.status_code == 200 and TOKEN_COOKIE in first.headers["Set-Cookie"]
    assert client.get("/api/runs").status_code == 200  # the cookie from the first request
    assert "HttpOnly" in first.headers["Set-Cookie"]


def test_loopback_without_token_refuses_foreign_host_headers(client) -> None:  # type: ignore[no-untyped-def]
    assert client.get("/api/runs", headers={"Host": "evil.example:8050"}).status_code == 403
    assert client.get("/api/runs", headers={"Host": "localhost:8050"}).status_code == 200
    assert client.get("/api/runs", headers={"Host": "[::1]:8050"}).status_code == 200


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_cli_bad_input(logs: Path, tmp_path: Path) -> None:
    """In this process: each error ends before the server starts. (``sbagents.dashboard`` is a package: its
    ``main`` is in ``__main__``, which ``cli`` imports by name.)"""
    missing = cli("dashboard.__main__", "-f", str(tmp_path / "nope"))
    assert missing.returncode == 2 and len(missing.stderr.strip().splitlines()) == 1
    assert "no such folder" in missing.stderr and "Traceback" not in missing.stderr
    exposed = cli("dashboard.__main__", "-f", str(logs), "--host", "0.0.0.0")
    assert exposed.returncode == 2 and "--token" in exposed.stderr and len(exposed.stderr.strip().splitlines()) == 1
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        taken = cli("dashboard.__main__", "-f", str(logs), "--port", str(port))
    assert taken.returncode == 2 and "in use" in taken.stderr and len(taken.stderr.strip().splitlines()) == 1


def test_cli_serves_and_stops_on_sigint(logs: Path) -> None:
    import urllib.request

    port = _free_port()
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    # a subprocess on purpose: a real server, stopped by Ctrl-C (SIGINT)
    proc = subprocess.Popen([sys.executable, "-m", "sbagents.dashboard", "-f", str(logs), "--port", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            preexec_fn=default_sigint)
    try:
        line = proc.stdout.readline() if proc.stdout else ""
        assert f"http://127.0.0.1:{port}/" in line
        deadline = time.monotonic() + 30
        while True:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/runs") as response:
                    runs = json.load(response)["runs"]
                break
            except OSError:
                assert time.monotonic() < deadline, "the dashboard did not answer"
                time.sleep(0.2)
        assert runs[0]["id"] == f"0/{RUN}"
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/static/plotly.min.js") as response:
            assert b"plotly" in response.read(2000).lower()
    finally:
        proc.send_signal(2)
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0 and "stopped" in out and "Traceback" not in err


def test_the_dashboard_loads_neither_torch_nor_sb3() -> None:
    code = ("import sys, sbagents.dashboard.__main__, sbagents.dashboard.app; "
            "print(sorted(m for m in ('torch', 'stable_baselines3') if m in sys.modules))")
    # a subprocess on purpose: what a fresh interpreter imports (this one has torch loaded already)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_without_flask_one_line_says_what_to_install(logs: Path) -> None:
    code = ("import sys; sys.modules['flask'] = None; from sbagents.cli_common import run; "
            "from sbagents.dashboard.__main__ import main; "
            "run('python -m sbagents.dashboard', lambda: main(sys.argv[1:]))")
    # a subprocess on purpose: simulates a missing dependency (Flask), which this interpreter has imported
    proc = subprocess.run([sys.executable, "-c", code, "-f", str(logs)], capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stderr.strip().splitlines() == [
        "python -m sbagents.dashboard: error: the dashboard needs Flask and plotly (flask is missing): "
        "pip install 'sbagents[dashboard]'"
    ]


def test_runs_benchmark_lists_every_run_and_its_section_is_the_saved_result() -> None:
    from benchmarks.speed import dashboard_runs

    result = dashboard_runs.run(["--runs", "8"])
    assert result["listed"] == 8 and result["command"] == "python -m benchmarks run dashboard-runs --runs 8"
    assert "| first (every run read; the baseline) |" in dashboard_runs.markdown(result)
    root = Path(__file__).resolve().parents[1]
    saved = json.loads((root / "benchmarks" / "results" / "dashboard_runs.json").read_text())
    text = (root / "BENCHMARKS.md").read_text()
    section = text.split("<!-- dashboard-runs:start -->\n")[1].split("\n<!-- dashboard-runs:end -->")[0]
    assert section.strip() == dashboard_runs.markdown(saved).strip()


def test_episode_costs_of_a_growing_multi_member_gzip_log(tmp_path: Path) -> None:
    """EpCost read in small budgets from a ``.csv.gz`` log appended in two gzip members, then garbage: every episode
    is summed once, in order, and a broken tail ends the reading instead of raising."""
    import gzip

    from sbagents.dashboard.episode_costs import EpisodeCosts

    header = "episode,step,reward,terminated,truncated,violation,cost\n"
    rows = [f"{ep},{s},-1,{s == 9},False,{'hot' if s == ep else ''},{1.0 if s == ep else 0.0}\n"
            for ep in range(8) for s in range(10)]
    path = tmp_path / "transparency.csv.gz"
    for part in (header + "".join(rows[:35]), "".join(rows[35:])):
        with gzip.open(path, "ab", compresslevel=1) as fh:
            fh.write(part.encode())
    reader = EpisodeCosts(path)
    result = reader.update(byte_budget=64)
    assert result["progress"] < 1.0
    while result["progress"] < 1.0:
        result = reader.update(byte_budget=64)
    assert result["ep_cost"] == [1.0] * 8 and result["violations"] == [1] * 8 and result["lengths"] == [10] * 8
    with path.open("ab") as fh:
        fh.write(b"not gzip at all")
    assert reader.update(byte_budget=64)["ep_cost"] == [1.0] * 8


def test_a_constrained_run_shows_its_multiplier_and_episode_costs(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """A real ``train --constraint`` run with a transparency log: the trust view gets the multiplier's history from
    safety.json and each training episode's cost from the log (the hazard grid's cost column)."""
    monkeypatch.setenv("SBAGENTS_CACHE_DIR", str(tmp_path / "cache"))
    trained = cli("train", "--algo", "ppo", "--env", "sbagents/HazardGridWorld-v0", "-n", "512", "-f",
                  str(tmp_path / "logs"), "--seed", "0", "--constraint", "lagrangian", "--cost-limit", "0.5",
                  "--eval-freq", "0", "--final-eval-episodes", "0", "--transparency-log", "-params", "n_envs:4",
                  "n_steps:64", "batch_size:64")
    assert trained.returncode == 0, trained.stderr
    client = create_app(ServedFolders.from_paths([tmp_path / "logs"])).test_client()
    trust = client.get("/api/trust/0/ppo/sbagents_HazardGridWorld-v0_1").get_json()
    constraint = trust["safety"][0]["constraint"]
    assert constraint["method"] == "lagrangian" and constraint["cost_limit"] == 0.5
    assert len(constraint["history"]) >= 2 and constraint["multiplier"] == constraint["history"][-1]["multiplier"]
    costs = trust["ep_cost"]
    assert costs["has_cost"] and len(costs["ep_cost"]) > 0 and costs["progress"] == 1.0
    assert sum(costs["ep_cost"]) == sum(costs["violations"])  # one cost per hazard step
