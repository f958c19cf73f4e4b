"""sbagents.dashboard against hostile run dirs: symlinks that lead out of the served folder (files and folders),
FIFOs, binary and malformed files of every kind the dashboard reads, bad query values, a walk over every route of the
app (``app.url_map``, so a route added later is walked too) asserting no 5xx, per-log locks, and the bounds on
header reads and on monitor-file memory (limits patched down: no big files are written)."""

from __future__ import annotations

import inspect
import io
import json
import os
import re
import threading
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlencode

import numpy as np
import pytest

pytest.importorskip("flask")

from flask import Flask  # noqa: E402
from flask.testing import FlaskClient  # noqa: E402

from sbagents.dashboard import app as app_module  # noqa: E402
from sbagents.dashboard import episode_costs, logindex, monitors, queryargs, safeload  # noqa: E402
from sbagents.dashboard.app import create_app  # noqa: E402
from sbagents.dashboard.folders import ServedFolders  # noqa: E402
from sbagents.dashboard.logindex import LogIndex  # noqa: E402
from tests.test_dashboard import RUN, write_run  # noqa: E402

ENV_DIR = "sbagents_SmartHome-v0"
#: What the files outside the served folder hold; no response may contain it.
SECRET = "s3cr3t-outside-the-served-folder"
SECRET_NUMBER = 4242.25
BINARY = bytes(range(256)) * 8
#: Seconds a request may take before a test calls it hung (a guard against deadlocks, not a speed check).
HANG_S = 60


@pytest.fixture(autouse=True)
def _cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SBAGENTS_CACHE_DIR", str(tmp_path / "cache"))


def served(folder: Path) -> Flask:
    """The app over ``folder``; exceptions propagate, so a failing route shows its traceback."""
    app = create_app(ServedFolders.from_paths([folder]))
    app.config["PROPAGATE_EXCEPTIONS"] = True
    return app


def leaks(body: bytes) -> bool:
    return SECRET.encode() in body or str(SECRET_NUMBER).encode() in body


# ---------------------------------------------------------------------------------------------------- outside
def write_outside(folder: Path) -> dict[str, Path]:
    """Files outside the served folder, each in the format of one run file, each holding :data:`SECRET`."""
    folder.mkdir(parents=True, exist_ok=True)
    secret_log = ("env,episode,step,reward,terminated,truncated,violation,cost\n"
                  f"0,0,0,{SECRET_NUMBER},True,False,{SECRET},1\n")
    files = {
        "text": ("secret.txt", f"{SECRET}\n"),
        "json": ("secret.json", json.dumps({"algo": SECRET, "fps": SECRET_NUMBER, "total_violations": SECRET_NUMBER})),
        "yaml": ("secret.yml", f"algo: {SECRET}\nseed: 7\nlearning_rate: {SECRET_NUMBER}\n"),
        "monitor": ("secret.monitor.csv", f'#{{"t_start": 0}}\nr,l,t\n{SECRET_NUMBER},7,1\n'),
        "log": ("secret_log.csv", secret_log),
        "adversarial": ("secret_adv.csv", f"timesteps,attack,eps,mean_return\n60,{SECRET},0.1,{SECRET_NUMBER}\n"),
        "fairness": ("secret_fair.csv", f"{SECRET}_low,{SECRET}_high,n,success_rate\n0,1,4,{SECRET_NUMBER}\n"),
    }
    out = {}
    for kind, (name, text) in files.items():
        (folder / name).write_text(text)
        out[kind] = folder / name
    np.savez(folder / "secret.npz", timesteps=np.array([SECRET_NUMBER]), results=np.array([[SECRET_NUMBER]]))
    out["npz"] = folder / "secret.npz"
    with zipfile.ZipFile(folder / "secret.zip", "w") as archive:
        archive.writestr("data", json.dumps({"action_space": {":type:": "Box", "_shape": [4242]}}))
    out["zip"] = folder / "secret.zip"
    for name in ("cfg", "videos", "export"):
        (folder / name).mkdir(exist_ok=True)
    (folder / "cfg" / "args.yml").write_text(files["yaml"][1])
    (folder / "cfg" / "config.yml").write_text(files["yaml"][1])
    (folder / "videos" / "y.csv").write_text(secret_log)
    (folder / "videos" / "y.mp4").write_text(SECRET)
    (folder / "export" / "policy.onnx").write_text(SECRET)
    write_run(folder / "runs", "ddpg/sbagents_SmartHome-v0_9")
    (folder / "runs" / "ddpg" / "sbagents_SmartHome-v0_9" / "summary.json").write_text(json.dumps({"algo": SECRET}))
    return out


#: (name in the run dir, kind of outside file it is linked to; a folder kind links a folder).
LINKS = [
    ("command.txt", "text"), ("summary.json", "json"), (f"{ENV_DIR}/config.yml", "yaml"),
    (f"{ENV_DIR}/args.yml", "yaml"), ("0.monitor.csv", "monitor"), ("1.monitor.csv", "monitor"),
    ("transparency.csv", "log"), ("transparency_2.csv", "log"), ("videos/clip.csv", "log"),
    ("evaluations.npz", "npz"), ("safety.json", "json"), ("safety_group.json", "json"),
    ("adversarial.csv", "adversarial"), ("fairness.csv", "fairness"), ("best_model.zip", "zip"),
    ("model.zip", "zip"), (ENV_DIR, "dir:cfg"), ("videos", "dir:videos"), ("export", "dir:export"),
]


def link(run_dir: Path, name: str, target: Path) -> None:
    path = run_dir / name
    if path.is_dir() and not path.is_symlink():
        import shutil

        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()
    path.symlink_to(target, target_is_directory=target.is_dir())


def run_urls(run_id: str, logs: list[str]) -> Iterator[str]:
    """Every page and JSON endpoint of one run (and its files and logs by name)."""
    yield "/api/runs"
    for api in ("curves", "settings", "trust"):
        yield f"/api/{api}/{run_id}"
    for page in ("run", "decisions", "trust"):
        yield f"/{page}/{run_id}"
    yield f"/api/compare?run={run_id}"
    for log in logs:
        yield f"/api/decisions/{run_id}?" + urlencode({"log": log, "count": 50})
        yield f"/api/decisions/{run_id}?" + urlencode({"log": log, "violations": 1})
        yield f"/api/decisions/{run_id}?" + urlencode({"log": log, "tail": 1})
        yield f"/api/episode/{run_id}?" + urlencode({"log": log, "episode": 0})
        yield f"/file/{run_id}/{log}"


@pytest.mark.parametrize(("name", "kind"), LINKS, ids=[n for n, _ in LINKS])
def test_symlinks_that_lead_out_are_missing_files(tmp_path: Path, name: str, kind: str) -> None:
    """A run file or folder that is a symlink out of the served folder is never read: nothing of its target is in
    any response, the run's logs and files do not list it, ``/file/`` and ``?log=`` answer 404."""
    outside = write_outside(tmp_path / "outside")
    logs = tmp_path / "logs"
    run_dir = write_run(logs)
    target = tmp_path / "outside" / kind[4:] if kind.startswith("dir:") else outside[kind]
    link(run_dir, name, target)
    client = served(logs).test_client()
    settings = client.get(f"/api/settings/0/{RUN}").get_json()
    listed = settings["logs"] + [e["path"] for entries in settings["files"].values() for e in entries]
    assert not [p for p in listed if p == name or p.startswith(name + "/")]
    for url in run_urls(f"0/{RUN}", [name, "transparency.csv", "videos/y.csv", "videos/clip.csv"]):
        response = client.get(url)
        assert response.status_code < 500 and not leaks(response.data), url
    assert client.get(f"/file/0/{RUN}/{name}").status_code == 404
    if name.endswith(".csv") and "monitor" not in name:
        assert client.get(f"/api/decisions/0/{RUN}?log={name}").status_code == 404
    if name == "command.txt":
        assert settings["command"] is None
    if name == "summary.json":  # the run is still listed, from args.yml and its monitor file
        row = client.get("/api/runs").get_json()["runs"][0]
        assert row["algo"] == "ddpg" and row["steps"] == 60


def test_a_symlinked_run_dir_or_folder_is_not_served(tmp_path: Path) -> None:
    write_outside(tmp_path / "outside")
    logs = tmp_path / "logs"
    write_run(logs)
    (logs / "ppo").symlink_to(tmp_path / "outside" / "runs" / "ddpg", target_is_directory=True)
    (logs / "ddpg" / "sbagents_SmartHome-v0_9").symlink_to(tmp_path / "outside" / "runs" / "ddpg" /
                                                           "sbagents_SmartHome-v0_9", target_is_directory=True)
    client = served(logs).test_client()
    runs = client.get("/api/runs")
    assert [r["id"] for r in runs.get_json()["runs"]] == [f"0/{RUN}"] and not leaks(runs.data)
    for run_id in ("0/ddpg/sbagents_SmartHome-v0_9", "0/ppo/sbagents_SmartHome-v0_9"):
        for url in run_urls(run_id, ["transparency.csv", "summary.json"]):
            response = client.get(url)
            assert (response.status_code == 404 or url == "/api/runs") and not leaks(response.data), url


FIFO_SETS = [  # a run dir needs one regular marker file (command.txt, evaluations.npz) to be served
    ["summary.json", f"{ENV_DIR}/args.yml", f"{ENV_DIR}/config.yml", "0.monitor.csv", "1.monitor.csv",
     "evaluations.npz", "safety.json", "adversarial.csv", "fairness.csv", "transparency_fifo.csv", "best_model.zip",
     "videos/clip.csv"],
    ["command.txt", "videos/clip.csv", "export"],
]


@pytest.mark.parametrize("names", FIFO_SETS, ids=["most", "command"])
def test_fifos_are_not_opened(tmp_path: Path, names: list[str]) -> None:
    """A FIFO in place of a run file would block the request that opens it forever: it is no file."""
    logs = tmp_path / "logs"
    run_dir = write_run(logs)
    for name in names:
        path = run_dir / name
        if path.exists():
            path.unlink()
        os.mkfifo(path)
    client = served(logs).test_client()
    done: list[int] = []

    def visit() -> None:
        for url in run_urls(f"0/{RUN}", ["transparency_fifo.csv", "transparency.csv", "videos/clip.csv"]):
            done.append(client.get(url).status_code)

    thread = threading.Thread(target=visit, daemon=True)
    thread.start()
    thread.join(HANG_S)
    assert not thread.is_alive(), "a request blocked on a FIFO"
    assert done and max(done) < 500 and client.get(f"/run/0/{RUN}").status_code == 200
    settings = client.get(f"/api/settings/0/{RUN}").get_json()
    assert settings["logs"] == ["transparency.csv"] and settings["files"]["exports"] == []


# ---------------------------------------------------------------------------------------------------- garbage
class _Boom:
    """Unpickling this runs :func:`_boom` (it must never happen)."""

    def __reduce__(self) -> tuple[Callable[[], None], tuple[()]]:
        return _boom, ()


UNPICKLED: list[bool] = []


def _boom() -> None:
    UNPICKLED.append(True)


def npz_bytes(**arrays: Any) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def npz_lying_header() -> bytes:
    """An npz whose ``timesteps`` header promises 10**12 floats (8 TB) in a few bytes."""
    member = io.BytesIO()
    np.lib.format.write_array_header_1_0(member, {"descr": "<f8", "fortran_order": False, "shape": (10**12,)})
    member.write(b"\x00" * 64)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as archive:
        archive.writestr("timesteps.npy", member.getvalue())
        archive.writestr("results.npy", member.getvalue())
    return buf.getvalue()


def model_zip(data: bytes) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as archive:
        archive.writestr("data", data)
    return buf.getvalue()


ALIAS_BOMB = "a: &a [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join([f'*{chr(97 + i)}'] * 10)}]\n" for i in range(8))
YAML_GARBAGE = [
    BINARY, b"- a\n- b\n", b"a: [b\n", b"[" * 5000, ALIAS_BOMB.encode(), b"seed: 2001-13-45\n",
    b"a: !!set {x, y}\nb: !!binary aGVsbG8=\nc: 2020-01-01\n", b"timesteps_per_env_step: .inf\nseed: .nan\n",
    b"!!python/object/apply:os.system ['echo pwned']\n", b"algo: " + b"x" * 300 + b"\n" + b"k: [" * 60 + b"]" * 60,
]
#: name -> contents to try (bytes, or a function of the run dir that writes the file).
GARBAGE: dict[str, list[bytes]] = {
    "command.txt": [BINARY, b"\x00" * 64, b"\xff\xfe" + "python train".encode("utf-16-le")],
    "summary.json": [
        BINARY, b"[" * 100_000, b"[1, 2]", b'"text"', b'{"algo": {"a": 1}, "interrupted": [1], "eval": [2]}',
        b'{"seed": Infinity, "fps": 1e999, "n_timesteps": ' + b"9" * 400 + b', "eval": {"mean_return": "x"}}',
        b'{"seed": ' + b"9" * 5000 + b"}", b'{"algo": "ddpg", "n_timest',
    ],
    f"{ENV_DIR}/args.yml": YAML_GARBAGE,
    f"{ENV_DIR}/config.yml": YAML_GARBAGE,
    "0.monitor.csv": [
        BINARY, b"#" + b"{" * 5000 + b"\nr,l,t\n1,1,1\n", b'#{"t_start": "x"}\nr,l,t\n1,1,1\n',
        b"#[1]\nq,w\n1,2\n", b"r,l,t\nnan,inf,-inf\n1e400,-1e400,1\n", b'#{"t_start": 1e999}\nr,l,t\n1,1,1\n',
        b'#{}\nr,l,t\n"1,1,1\n\r\r,\r\n' + b'"' + b"x" * 200_000 + b'",1,1\n',
    ],
    "evaluations.npz": [
        BINARY, b"PK\x03\x04 truncated", npz_lying_header(),
        npz_bytes(timesteps=np.array([1]), results=np.array([[1.0]]), successes=np.array(1.0)),
        npz_bytes(timesteps=np.array(["a", "b"]), results=np.array([["x"], ["y"]])),
        npz_bytes(timesteps=np.array([1, 2, 3]), results=np.ones((2, 5))),
        npz_bytes(timesteps=np.array(5), results=np.ones(3)),
        npz_bytes(timesteps=np.array([1, 2]), results=np.ones((2, 2)), successes=np.ones((3, 7))),
        npz_bytes(timesteps=np.array([_Boom()], dtype=object), results=np.array([_Boom()], dtype=object)),
        npz_bytes(results=np.ones((2, 2))),
    ],
    "transparency.csv": [
        BINARY, b"\r\r\r\n\r,\r\n", b'env,episode\n"' + b"x" * 200_000 + b'"\n', b"env,episode,step\n",
        b"episode,step\n" + b"\xff\xfe,1\n" * 10, b'"unclosed,header\n0,1\n', b"\x00" * 5000,
        b"env,episode,step,reward,cost\n" + b"1,1e400,nan,-inf,inf\n" * 3,
    ],
    "videos/clip.csv": [BINARY, b"frame,episode\n\x00,\x00\n"],
    "safety.json": [BINARY, b"[1, 2]", b'{"violations": "x", "ep_cost": 5, "constraint": [1]}', b"{" * 3000],
    "adversarial.csv": [BINARY, b'timesteps,attack,eps,mean_return\n1,"' + b"x" * 200_000 + b'",1,1\n',
                        b"timesteps,attack,eps,mean_return\n1,fgsm,inf,nan\n1,none\n,,,,,,,\n"],
    "fairness.csv": [BINARY, b"a_low,a_high,n\nx,y,z\n", b"\n\n", b",,,\n1,2,3,4,5\n"],
    "best_model.zip": [BINARY, model_zip(b"[" * 100_000), model_zip(b'{"action_space": {"_shape": [1e300]}}'),
                       model_zip(b'{"action_space": {"nvec": 5, ":type:": "MultiDiscrete"}}')],
}
CASES = [(name, i) for name, contents in GARBAGE.items() for i in range(len(contents))]
#: Where the note about each file shows (for its first, binary content).
NOTE_IN = {"command.txt": "settings", "summary.json": "settings", f"{ENV_DIR}/args.yml": "settings",
           f"{ENV_DIR}/config.yml": "settings", "0.monitor.csv": "curves", "evaluations.npz": "curves",
           "safety.json": "trust", "adversarial.csv": "trust", "fairness.csv": "trust"}


@pytest.mark.parametrize(("name", "case"), CASES, ids=[f"{n}-{i}" for n, i in CASES])
def test_garbage_files_give_notes_never_5xx(tmp_path: Path, name: str, case: int) -> None:
    logs = tmp_path / "logs"
    run_dir = write_run(logs)
    (run_dir / name).write_bytes(GARBAGE[name][case])
    client = served(logs).test_client()
    for url in run_urls(f"0/{RUN}", ["transparency.csv", "videos/clip.csv"]):
        response = client.get(url)
        assert response.status_code < 500, url
        if url.startswith("/api/"):
            json.dumps(response.get_json(), allow_nan=False)  # JSON the browser parses: no NaN, no Infinity
    if case == 0 and name in NOTE_IN:
        notes = " ".join(client.get(f"/api/{NOTE_IN[name]}/0/{RUN}").get_json()["notes"])
        assert Path(name).name in notes
    assert not UNPICKLED


def test_yaml_alias_bomb_and_deep_nesting_are_notes(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    run_dir = write_run(logs)
    (run_dir / ENV_DIR / "args.yml").write_text(ALIAS_BOMB)
    (run_dir / ENV_DIR / "config.yml").write_text("[" * 5000 + "]" * 5000)
    settings = served(logs).test_client().get(f"/api/settings/0/{RUN}").get_json()
    assert settings["args"] is None and settings["config"] is None
    notes = " ".join(settings["notes"])
    assert "args.yml could not be read (DataTooComplex: more than" in notes and "config.yml could not be read" in notes


def test_over_long_files_are_not_read_whole(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(safeload, "SMALL_FILE_BYTES", 1000)
    monkeypatch.setattr(safeload, "NPZ_BYTES", 1000)
    logs = tmp_path / "logs"
    run_dir = write_run(logs)
    (run_dir / "command.txt").write_text("python -m sbagents.train " + "--x 1 " * 1000)
    np.savez(run_dir / "evaluations.npz", timesteps=np.arange(100), results=np.ones((100, 5)))
    client = served(logs).test_client()
    settings = client.get(f"/api/settings/0/{RUN}").get_json()
    assert settings["command"] is None and "command.txt is over 1000 B" in " ".join(settings["notes"])
    curves = client.get(f"/api/curves/0/{RUN}").get_json()
    assert curves["eval"]["mean"] == [] and "evaluations.npz could not be read" in " ".join(curves["notes"])


def test_npz_object_arrays_are_never_unpickled(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    run_dir = write_run(logs)
    (run_dir / "evaluations.npz").write_bytes(GARBAGE["evaluations.npz"][8])
    curves = served(logs).test_client().get(f"/api/curves/0/{RUN}").get_json()
    assert curves["eval"]["mean"] == [] and "object arrays are not read" in " ".join(curves["notes"])
    assert not UNPICKLED


# ---------------------------------------------------------------------------------------------------- queries
BAD_NUMBERS = ["x", "inf", "-inf", "nan", "NaN", "1e400", "-1e400", "9" * 30, "9" * 5000, "-1", "0x10", "1_0", "\x00",
               "١", "²"]


@pytest.mark.parametrize("name", ["step_min", "step_max", "reward_min", "reward_max"])
@pytest.mark.parametrize("value", ["x", "inf", "-inf", "nan", "1e400", "-1e400", "\x00", "1e"])
def test_non_finite_bounds_are_400(tmp_path: Path, name: str, value: str) -> None:
    logs = tmp_path / "logs"
    write_run(logs)
    response = served(logs).test_client().get(f"/api/decisions/0/{RUN}?" + urlencode({"log": "transparency.csv",
                                                                                     name: value}))
    assert response.status_code == 400 and name.encode() in response.data


@pytest.mark.parametrize(("api", "name"), [("decisions", "start"), ("decisions", "count"), ("decisions", "cursor"),
                                           ("decisions", "episode"), ("decisions", "env"), ("episode", "episode"),
                                           ("episode", "env")])
@pytest.mark.parametrize("value", ["x", "-1", "1.5", "inf", "nan", "1e400", "9" * 19, "9" * 5000, "0x10", "١", "²"])
def test_bad_integers_are_400(tmp_path: Path, api: str, name: str, value: str) -> None:
    logs = tmp_path / "logs"
    write_run(logs)
    response = served(logs).test_client().get(f"/api/{api}/0/{RUN}?" + urlencode({"log": "transparency.csv",
                                                                                 name: value}))
    assert response.status_code == 400 and name.encode() in response.data


def test_in_range_values_that_match_nothing(tmp_path: Path) -> None:
    """Values that parse but name nothing: unknown logs, runs and folders answer 404, filters match no row."""
    logs = tmp_path / "logs"
    write_run(logs)
    client = served(logs).test_client()
    api = f"/api/decisions/0/{RUN}?log=transparency.csv"
    for query in ("&start=9223372036854775807", "&cursor=9223372036854775807&episode=1", "&episode=9223372036854775807",
                  "&env=77", "&agent=nobody", "&step_min=1e300", "&step_max=-1e300", "&reward_min=1e308"):
        page = client.get(api + query).get_json()
        assert page["rows"] == [], query
    assert client.get(api + "&step_min=2.5&step_max=3.5&episode=0").get_json()["row_numbers"] == [3]
    episode = client.get(f"/api/episode/0/{RUN}?log=transparency.csv&episode=1&env=5").get_json()
    assert episode["rows"] == [] and episode["video"] is None
    for url in (f"/api/decisions/0/{RUN}?log=nope.csv", f"/api/decisions/0/{RUN}?log=", f"/api/decisions/0/{RUN}",
                f"/api/episode/0/{RUN}?log=../transparency.csv", "/api/compare?run=0/nope", "/api/compare?run=9/x",
                "/api/compare?run=%C2%B2/x", "/api/compare?run=", f"/api/curves/9/{RUN}",
                f"/api/curves/99999999999999999999999/{RUN}", "/run/0/nope"):
        assert client.get(url).status_code == 404, url


# ---------------------------------------------------------------------------------------------------- every route
def query_names() -> set[str]:
    """Every query value the app reads (found in its source, so a new one is walked too)."""
    pattern = r"""(?:args\.get(?:list)?|int_arg|optional_int|float_arg)\(\s*["'](\w+)["']"""
    names = set()
    for module in (app_module, queryargs):
        names |= set(re.findall(pattern, inspect.getsource(module)))
    return names


#: Values of each URL argument a route may have (a route with another argument fails the walk: add its values).
URL_VALUES: dict[str, list[Any]] = {
    "root": [0, 1, 2**70], "rel": [RUN, "ddpg", "nope", "..", f"{RUN}/../../..", f"{RUN}/videos"],
    "filename": ["dashboard.js", "nope.js", "../app.py"],
}
#: Bad values, each given to every query name at once; the first :data:`N_EACH` also to each name on its own.
BAD_VALUES = ["x", "-1", "nan", "1e400", "9" * 30, "\x00", "../../../etc/passwd", "", "inf", "9" * 5000, "1.5", "%",
              "/etc/passwd", "transparency.csv", "videos/clip.csv", "0/" + RUN, "0", "1", "ü" * 50]
N_EACH = 7


def route_urls(app: Flask) -> Iterator[tuple[str, bool]]:
    """``(url, is_the_served_run)`` for every GET route of ``app`` and every combination of :data:`URL_VALUES`."""
    adapter = app.url_map.bind("localhost")
    for rule in app.url_map.iter_rules():
        if "GET" not in (rule.methods or ()):
            continue
        missing = set(rule.arguments) - set(URL_VALUES)
        assert not missing, f"route {rule.rule}: add values for {missing} to URL_VALUES"
        combos: list[dict[str, Any]] = [{}]
        for arg in sorted(rule.arguments):
            combos = [{**c, arg: v} for c in combos for v in URL_VALUES[arg]]
        for values in combos:
            url = adapter.build(rule.endpoint, values)
            yield url, (values.get("root", 0) == 0 and values.get("rel", RUN) == RUN
                        and values.get("filename", "dashboard.js") == "dashboard.js")


def walk(client: FlaskClient, app: Flask, queries: bool) -> int:
    """GET every route (with bad values of every query name when ``queries``); returns the number of requests."""
    names = sorted(query_names())
    good = {"log": "transparency.csv", "episode": "0", "run": f"0/{RUN}"}
    n = 0
    for url, is_run in route_urls(app):
        variants = [good]
        if queries and is_run:
            variants += [{name: value for name in names} for value in BAD_VALUES]
            variants += [{**good, name: value} for name in names for value in BAD_VALUES[:N_EACH]]
        for query in variants:
            response = client.get(url + "?" + urlencode(query))
            assert response.status_code < 500, (url, query)
            n += 1
    return n


def test_query_names_are_found() -> None:
    assert {"log", "start", "count", "cursor", "tail", "episode", "env", "agent", "step_min", "step_max",
            "reward_min", "reward_max", "violations", "run", "download", "token"} <= query_names()


def test_every_route_with_malformed_files_and_values_never_answers_5xx(tmp_path: Path) -> None:
    """Walks ``app.url_map``: every GET route, every URL argument value, every query name the app reads with every
    bad value, over a run dir where every file the dashboard reads is garbage (and one good run dir)."""
    logs = tmp_path / "logs"
    run_dir = write_run(logs)
    write_run(logs, "ppo/sbagents_SmartHome-v0_2")
    for name, contents in GARBAGE.items():
        (run_dir / name).write_bytes(contents[0])
    (run_dir / "videos" / "clip.csv").write_bytes(b"frame,episode,step\n1,0,0\n")
    app = served(logs)
    requests = walk(app.test_client(), app, queries=True)
    assert requests > 100 * len(list(app.url_map.iter_rules())) // 2
    for name in GARBAGE:  # the same walk, without bad values, over each kind of second garbage
        if len(GARBAGE[name]) > 1:
            (run_dir / name).write_bytes(GARBAGE[name][1])
    walk(app.test_client(), app, queries=False)


def test_every_route_of_a_good_run_with_bad_values_never_answers_5xx(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    run_dir = write_run(logs)
    (run_dir / "videos" / "clip.csv").write_text("frame,env,episode,step,reward\n0,0,0,0,1.0\n1,0,0,1,1.0\n")
    app = served(logs)
    walk(app.test_client(), app, queries=True)


# ---------------------------------------------------------------------------------------------------- big logs
def test_a_small_log_answers_while_a_big_log_is_opened_and_indexed(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """Opening a log (its header read) and indexing it hold only that log's lock: with the big log's opening, then
    its background indexing, held on an Event, a request for another log of the same run is answered."""
    logs = tmp_path / "logs"
    run_dir = write_run(logs)
    big = run_dir / "transparency_big.csv"
    big.write_text((run_dir / "transparency.csv").read_text())
    opening, indexing = threading.Event(), threading.Event()
    release_open, release_index = threading.Event(), threading.Event()
    init, scan = LogIndex.__init__, LogIndex._scan_step

    def held_init(self: LogIndex, path: Path, *args: Any, **kwargs: Any) -> None:
        if Path(path).name == big.name:
            opening.set()
            release_open.wait(HANG_S)
        init(self, path, *args, **kwargs)

    def held_scan(self: LogIndex) -> bool:
        if self.path.name == big.name and threading.current_thread().name == "sbagents-log-index":
            indexing.set()
            release_index.wait(HANG_S)
        return scan(self)

    monkeypatch.setattr(LogIndex, "__init__", held_init)
    monkeypatch.setattr(LogIndex, "_scan_step", held_scan)
    app = served(logs)
    answers: dict[str, Any] = {}

    def get(key: str, log: str) -> None:
        answers[key] = app.test_client().get(f"/api/decisions/0/{RUN}?log={log}&count=5")

    def answered_meanwhile(key: str) -> bool:
        thread = threading.Thread(target=get, args=(key, "transparency.csv"), daemon=True)
        thread.start()
        thread.join(HANG_S)
        return not thread.is_alive()

    big_request = threading.Thread(target=get, args=("big", big.name), daemon=True)
    big_request.start()
    try:
        assert opening.wait(HANG_S)
        assert answered_meanwhile("while opening"), "the small log waited for the big one to open"
        assert answers["while opening"].get_json()["row_numbers"] == [0, 1, 2, 3, 4]
        release_open.set()
        assert indexing.wait(HANG_S)  # the big log is open; its background indexing holds its lock now
        assert answered_meanwhile("while indexing"), "the small log waited for the big one's indexing"
        assert answers["while indexing"].get_json()["total_rows"] == 60
    finally:
        release_open.set()
        release_index.set()
        big_request.join(HANG_S)
    assert answers["big"].status_code == 200 and answers["big"].get_json()["row_numbers"] == [0, 1, 2, 3, 4]


def test_a_log_without_newline_reads_only_its_header_limit(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(logindex, "MAX_HEADER_BYTES", 1000)
    monkeypatch.setattr(logindex, "FIRST_STEP_BYTES", 256)
    monkeypatch.setattr(episode_costs, "MAX_LINE_BYTES", 1000)
    logs = tmp_path / "logs"
    run_dir = write_run(logs)
    (run_dir / "transparency.csv").unlink()
    (run_dir / "transparency.csv").write_bytes(b"x" * 200_000)
    client = served(logs).test_client()
    page = client.get(f"/api/decisions/0/{RUN}?log=transparency.csv").get_json()
    assert page["rows"] == [] and page["columns"] == [] and page["complete"]
    assert "its first line is over 1,000 bytes" in " ".join(page["notes"])
    from sbagents.dashboard.logregistry import open_log

    index = open_log(run_dir / "transparency.csv")
    assert index.bytes_scanned < 4 * 1000 and index.problem is not None
    for query in ("violations=1", "tail=1", "episode=0"):
        assert client.get(f"/api/decisions/0/{RUN}?log=transparency.csv&{query}").get_json()["rows"] == []
    trust = client.get(f"/api/trust/0/{RUN}").get_json()
    assert trust["ep_cost"]["ep_cost"] == [] and "its first line is over 1,000 bytes" in " ".join(trust["notes"])


def test_episode_costs_skip_an_over_long_row(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(episode_costs, "MAX_LINE_BYTES", 100)
    path = tmp_path / "transparency.csv"
    rows = [f"0,{ep},{s},{s == 2},{'hot' if s == 1 else ''},{1.0 if s == 1 else 0.0}\n"
            for ep in range(3) for s in range(3)]
    rows.insert(4, "9," * 300 + "\n")
    path.write_text("env,episode,step,terminated,violation,cost\n" + "".join(rows))
    reader = episode_costs.EpisodeCosts(path)
    result = reader.update(byte_budget=64)
    while result["progress"] < 1.0:
        assert len(reader.lines_in.carry) <= 100 + 64
        result = reader.update(byte_budget=64)
    assert result["problem"] is None and len(result["ep_cost"]) == 3


# ---------------------------------------------------------------------------------------------------- monitors
def write_monitor(path: Path, n: int, t_start: float = 1000.0, offset: float = 0.0) -> list[tuple[float, int]]:
    """``n`` episodes with return ``i + offset`` and length ``1 + i % 7``; returns ``(return, length)`` in order."""
    rows = [(i + offset, 1 + i % 7, (i + 1) * 0.5) for i in range(n)]
    path.write_text(f'#{{"t_start": {t_start}}}\nr,l,t\n' + "".join(f"{r},{ln},{t}\n" for r, ln, t in rows))
    return [(r, ln) for r, ln, _ in rows]


def test_monitor_files_stream_in_bounded_memory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A monitor file far over the limits (patched down) is read a budget per request and kept decimated: the
    curve has at most MAX_POINTS episodes, each at its exact cumulative timestep; totals are exact."""
    monkeypatch.setattr(monitors, "READ_BYTES", 4000)
    monkeypatch.setattr(monitors, "CHUNK_BYTES", 700)
    monkeypatch.setattr(monitors, "MAX_KEPT", 40)
    monkeypatch.setattr(monitors, "MAX_POINTS", 25)
    logs = tmp_path / "logs"
    run_dir = write_run(logs)
    (run_dir / "summary.json").unlink()
    episodes = write_monitor(run_dir / "0.monitor.csv", 3000)
    cumulative = np.cumsum([ln for _, ln in episodes]) * 2.0  # args.yml says 2 timesteps per env step
    (run_dir / ENV_DIR / "args.yml").write_text("algo: ddpg\nenv: sbagents/SmartHome-v0\ntimesteps_per_env_step: 2\n")
    client = served(logs).test_client()
    size = (run_dir / "0.monitor.csv").stat().st_size
    offsets = [0]
    for _ in range(size // 8000 + 2):
        curves = client.get(f"/api/curves/0/{RUN}").get_json()
        monitor = monitors._FILES[(run_dir / "0.monitor.csv").resolve()]
        offsets.append(monitor.offset)
        # the run's row (no summary.json: steps from the monitor files) and its curve read 4000 bytes each at most
        assert offsets[-1] - offsets[-2] <= 2 * 4000 and len(monitor.kept()["index"]) <= 40
        if not any("% read" in note for note in curves["notes"]):
            break
    assert offsets[-1] == size and len(offsets) > 5
    train = curves["train"]
    assert train["episodes"] == 3000 and 10 <= len(train["returns"]) <= 25
    assert train["timesteps"] == [cumulative[int(r)] for r in train["returns"]]
    assert train["lengths"] == [1 + int(r) % 7 for r in train["returns"]]
    assert client.get("/api/runs").get_json()["runs"][0]["steps"] == sum(ln for _, ln in episodes)


def test_monitor_files_merge_by_end_time_like_the_plots(tmp_path: Path) -> None:
    """Without decimation the dashboard's curve is what :func:`read_monitor_files` (the plots' reader) gives."""
    from sbagents.core.monitor_files import read_monitor_files

    logs = tmp_path / "logs"
    run_dir = write_run(logs)
    write_monitor(run_dir / "0.monitor.csv", 50, t_start=1000.0)
    write_monitor(run_dir / "1.monitor.csv", 40, t_start=1000.2, offset=0.5)
    with (run_dir / "1.monitor.csv").open("a") as fh:
        fh.write("oops,1\n7,7")  # a malformed row and a row being written
    train = served(logs).test_client().get(f"/api/curves/0/{RUN}").get_json()["train"]
    expected = read_monitor_files(run_dir)
    assert train["returns"] == expected.returns.tolist() and train["lengths"] == expected.lengths.tolist()
    assert train["timesteps"] == np.cumsum(expected.lengths).tolist()
    assert train["time"] == pytest.approx((expected.end_times - 1000.0).tolist())


def test_monitor_lines_over_the_limit_are_skipped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(monitors, "CHUNK_BYTES", 64)
    monkeypatch.setattr(monitors, "MAX_LINE_BYTES", 100)
    logs = tmp_path / "logs"
    run_dir = write_run(logs)
    (run_dir / "0.monitor.csv").write_text('#{"t_start": 0}\nr,l,t\n1,1,1\n' + "2" * 500 + ",1,2\n3,1,3\n")
    (run_dir / "1.monitor.csv").write_text("#" + "x" * 500)
    client = served(logs).test_client()
    curves = client.get(f"/api/curves/0/{RUN}").get_json()
    notes = " ".join(curves["notes"])
    assert curves["train"]["returns"] == [1.0, 3.0]
    assert "0.monitor.csv: 1 line(s) over 100 bytes skipped" in notes
    assert "1.monitor.csv: a first line over 100 bytes (not a monitor file)" in notes
    monitor = monitors._FILES[(run_dir / "1.monitor.csv").resolve()]
    assert monitor.offset <= 100 + 2 * 64


def test_hostile_benchmark_runs_and_its_section_is_the_saved_result() -> None:
    from benchmarks.suites import dashboard_hostile

    result = dashboard_hostile.run(["--mib", "2"])
    assert result["log"]["small_status"] == result["log"]["big_status"] == 200
    assert result["monitor"]["episodes"] > 50_000 and result["monitor"]["points"] <= monitors.MAX_POINTS
    root = Path(__file__).resolve().parents[1]
    saved = json.loads((root / "benchmarks" / "results" / "dashboard_hostile.json").read_text())
    text = (root / "BENCHMARKS.md").read_text()
    section = text.split("<!-- dashboard-hostile:start -->\n")[1].split("\n<!-- dashboard-hostile:end -->")[0]
    assert section.strip() == dashboard_hostile.markdown(saved).strip()
    tiny = dashboard_hostile.markdown(result)
    assert "| 2 MiB files | measured |" in tiny and "`python -m benchmarks run dashboard-hostile --mib 2`" in tiny


def test_a_long_row_right_after_the_header_is_skipped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The header and the start of an over-long row arrive in one chunk: the header is read, the row skipped."""
    monkeypatch.setattr(monitors, "MAX_LINE_BYTES", 100)
    monkeypatch.setattr(monitors, "CHUNK_BYTES", 200)
    logs = tmp_path / "logs"
    run_dir = write_run(logs)
    (run_dir / "0.monitor.csv").write_text('#{"t_start": 0}\nr,l,t\n' + "5" * 300 + ",1,1\n4,2,2\n")
    curves = served(logs).test_client().get(f"/api/curves/0/{RUN}").get_json()
    assert curves["train"]["returns"] == [4.0] and curves["train"]["timesteps"] == [2.0]
    assert "0.monitor.csv: 1 line(s) over 100 bytes skipped" in " ".join(curves["notes"])
