"""ONNX export (parity, int8, sidecar) and the torch-free serve loop."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3 import A2C, DDPG, DQN, PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.vec_env import VecNormalize

from sbagents.deploy.exporting import ExportChecks, ExportReport, export_run, format_report
from sbagents.deploy.onnx_export import export_onnx, quantize_int8
from sbagents.deploy.parity import INT8_TOLERANCE, check_parity, latency_table, record_observations

torch.set_num_threads(1)
SMART = "sbagents/SmartHome-v0"
GRID = "sbagents/GridWorld-v0"
for _id, _ep in (
    (SMART, "sbagents.envs.smart_home:SmartHomeEnv"),
    (GRID, "sbagents.envs.gridworld:GridWorldEnv"),
):
    if _id not in gym.registry:
        gym.register(id=_id, entry_point=_ep)
OBS_NAMES = ("Temperature", "Light_Level", "Time", "Preferred_Temp", "Preferred_Light")
ACTION_NAMES = ("Action_Temp", "Action_Light")
SMALL = {"net_arch": [16, 16]}


def _normalized_env(seed: int = 0) -> VecNormalize:
    """SmartHome under VecNormalize with non-trivial statistics (random actions for 300 steps)."""
    venv = VecNormalize(make_vec_env(SMART, n_envs=2, seed=seed), norm_reward=False)
    venv.action_space.seed(seed)
    venv.reset()
    for _ in range(150):
        venv.step(np.stack([venv.action_space.sample() for _ in range(2)]))
    venv.training = False
    return venv


def _rms(venv: VecNormalize) -> RunningMeanStd:
    assert isinstance(venv.obs_rms, RunningMeanStd)
    return venv.obs_rms


def _model(algo: type[BaseAlgorithm], env: Any) -> BaseAlgorithm:
    kwargs: dict[str, Any] = {"policy_kwargs": dict(SMALL), "seed": 0, "device": "cpu"}
    if algo in (SAC, TD3, DDPG, DQN):
        kwargs["buffer_size"] = 1000
    if algo is PPO:  # short rollouts: learn(200) is then ~40 gradient steps, not a 2,048-step rollout's 320
        kwargs.update(n_steps=64, batch_size=64)
    return algo("MlpPolicy", env, **kwargs)


@pytest.mark.parametrize("algo", [PPO, A2C, SAC, TD3, DDPG])
def test_box_parity_with_vecnormalize(algo: type[BaseAlgorithm], tmp_path: Path) -> None:
    venv = _normalized_env()
    model = _model(algo, venv)
    model.learn(200)  # moves weights away from init (and PPO/A2C log_std) without real training cost
    path = export_onnx(model, tmp_path / "p.onnx", _rms(venv), venv.clip_obs, venv.epsilon)
    obs = record_observations(gym.make(SMART), model, n=300, seed=1, vec_normalize=venv)
    assert obs.shape == (300, 5) and obs[:, 0].min() > 17 and obs[:, 1].max() < 101  # raw, not normalized
    assert check_parity(model, path, obs, venv) <= 1e-4
    # out-of-distribution observations hit the normalization clip and the action bounds
    wild = np.concatenate([obs, obs * 50.0, -obs])
    assert check_parity(model, path, wild, venv) <= 1e-4
    # without the statistics the actions differ: the normalization really is in the graph
    raw_path = export_onnx(model, tmp_path / "raw.onnx")
    assert check_parity(model, raw_path, obs, venv) > 1e-3


def test_discrete_actions_and_observations(tmp_path: Path) -> None:
    dqn = _model(DQN, make_vec_env(GRID, n_envs=1, seed=0))  # Discrete obs (one-hot in graph) and actions
    path = export_onnx(dqn, tmp_path / "dqn.onnx")
    obs = np.arange(25)
    assert check_parity(dqn, path, obs) == 0.0
    int8 = quantize_int8(path, tmp_path / "dqn.int8.onnx")
    assert int8.is_file()
    ppo = _model(PPO, make_vec_env("CartPole-v1", n_envs=1, seed=0))  # Box obs, Discrete actions
    path = export_onnx(ppo, tmp_path / "ppo.onnx")
    obs = record_observations(make_vec_env("CartPole-v1", n_envs=2), ppo, n=200, seed=3)
    assert check_parity(ppo, path, obs) == 0.0


def test_int8_and_latency(tmp_path: Path) -> None:
    venv = _normalized_env()
    model = _model(SAC, venv)
    path = export_onnx(model, tmp_path / "p.onnx", _rms(venv))
    q = quantize_int8(path, tmp_path / "p.int8.onnx")
    obs = record_observations(venv, model, n=100, seed=0)
    assert venv.training is False
    assert check_parity(model, q, obs, venv) < 0.5  # int8 is approximate but close (bounds are +-1/+-10)
    table = latency_table(model, {"onnx": path, "onnx_int8": q}, obs[0], n=50, vec_normalize=venv)
    assert set(table) == {"sb3_predict", "onnx", "onnx_int8"}
    assert all(set(row) == {"p50_us", "p99_us"} and np.isfinite(list(row.values())).all() for row in table.values())


@pytest.fixture(scope="module")
def exported(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[Path, ExportReport, BaseAlgorithm, VecNormalize]:
    out = tmp_path_factory.mktemp("export")
    venv = _normalized_env()
    model = _model(TD3, venv)
    model.learn(200)
    report = export_run(model, out, SMART, vec_normalize=venv, int8=True,
                        checks=ExportChecks(n_observations=300, latency_n=50))
    return out, report, model, venv


def test_export_run_writes_files(exported: tuple[Path, ExportReport, BaseAlgorithm, VecNormalize]) -> None:
    out, report, _, _ = exported
    assert report.onnx_path == out / "policy.onnx" and report.int8_path == out / "policy.int8.onnx"
    assert report.parity_fp32 <= 1e-4 and report.parity_int8 is not None and report.parity_int8 < 0.5
    assert report.n_parity_observations == 300 and report.int8_bytes and report.onnx_bytes
    meta = json.loads((out / "policy.json").read_text())
    assert meta["obs_names"] == list(OBS_NAMES) and meta["action_names"] == list(ACTION_NAMES)
    assert meta["env_id"] == SMART and meta["action_space"]["low"] == [-1.0, -10.0]
    assert meta["files"] == {"onnx": "policy.onnx", "onnx_int8": "policy.int8.onnx"}
    assert set(meta["report"]["latency"]) == {"sb3_predict", "onnx", "onnx_int8"}
    assert sorted(p.name for p in out.iterdir()) == ["policy.int8.onnx", "policy.json", "policy.onnx"]  # no staging


def test_int8_verdict_uses_the_action_range(
    exported: tuple[Path, ExportReport, BaseAlgorithm, VecNormalize]
) -> None:
    _, report, _, _ = exported
    assert report.action_kind == "box" and report.int8_deviation is not None and report.parity_int8 is not None
    # SmartHome's action ranges are 2 (thermostat) and 20 (light): the deviation is a share of them
    assert report.parity_int8 / 20 - 1e-9 <= report.int8_deviation <= report.parity_int8 / 2 + 1e-9
    assert report.int8_acceptable == (report.int8_deviation <= INT8_TOLERANCE["box"])
    text = format_report(report)
    assert f"{100 * report.int8_deviation:.1f}% of the action range (limit 5%)" in text
    assert ("acceptable" if report.int8_acceptable else "NOT acceptable") in text
    assert text.count("\n") == 3 and "{" not in text  # files, parity, int8, latency; no JSON dump


BLOCKER = (
    "import sys\n"
    "for m in ('torch', 'stable_baselines3', 'sb3_contrib', 'gymnasium'):\n"
    "    sys.modules[m] = None\n"
)

#: ``python -m sbagents.serve ARGS`` inside ``python -c`` (so modules can be blocked first)
RUN_SERVE = (
    "import runpy, sys\nsys.argv = ['serve'] + sys.argv[1:]\n"
    "runpy.run_module('sbagents.serve', run_name='__main__')\n"
)


def _run(code: str, stdin: str = "", args: tuple[str, ...] = ()) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    return subprocess.run(
        [sys.executable, "-c", code, *args], input=stdin, capture_output=True, text=True, timeout=60, env=env
    )


def test_serve_module_needs_no_torch_sb3_gymnasium() -> None:
    serve_py = Path(__file__).resolve().parents[1] / "sbagents" / "serve.py"
    code = BLOCKER + (
        "import importlib.util\n"
        f"spec = importlib.util.spec_from_file_location('serve_standalone', {str(serve_py)!r})\n"
        "mod = importlib.util.module_from_spec(spec); spec.loader.exec_module(mod)\n"
        "import onnxruntime\n"
        "print('ok', 'torch' in sys.modules and sys.modules['torch'] is not None)\n"
    )
    proc = _run(code)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "ok False"


def test_serve_end_to_end(
    exported: tuple[Path, ExportReport, BaseAlgorithm, VecNormalize], tmp_path: Path
) -> None:
    out, _, model, venv = exported
    good = [[22.0, 55.0, 3.0, 24.0, 70.0], [19.5, 80.0, 23.0, 21.0, 52.0]]
    named = dict(zip(OBS_NAMES, [25.0, 10.0, 12.0, 20.0, 60.0], strict=True))
    lines = [
        json.dumps(good[0]),
        "{not json",
        json.dumps(good[0][:4]),  # wrong length
        json.dumps({**named, "Humidity": 3}),  # unknown key
        json.dumps([22.0, "hot", 3.0, 24.0, 70.0]),  # non-number
        "[22.0, NaN, 3.0, 24.0, 70.0]",  # not finite
        "",  # blank: an error too (every line gets one reply)
        json.dumps(named),
        json.dumps(good[1]),
    ]
    csv_path = tmp_path / "decisions.csv"
    code = BLOCKER + RUN_SERVE  # torch, SB3 and gymnasium are blocked: only numpy + onnxruntime
    proc = _run(code, "\n".join(lines) + "\n", ("--model", str(out / "policy.onnx"), "--csv", str(csv_path)))
    assert proc.returncode == 0, proc.stderr
    replies = [json.loads(x) for x in proc.stdout.splitlines()]
    assert len(replies) == 9
    errors = [r for r in replies if isinstance(r, dict)]
    assert len(errors) == 6 and all("error" in e for e in errors)
    assert errors[2]["error"].startswith("unknown keys ['Humidity']; expected")  # no empty "missing keys []"
    assert errors[5]["error"].startswith("empty observation")
    actions = np.array([replies[0], replies[7], replies[8]])
    obs = np.array([good[0], [named[k] for k in OBS_NAMES], good[1]])
    expected, _ = model.predict(venv.normalize_obs(obs), deterministic=True)
    np.testing.assert_allclose(actions, expected, atol=1e-4)
    with csv_path.open() as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["timestamp", *OBS_NAMES, *ACTION_NAMES] and len(rows) == 4
    assert b"\r" not in csv_path.read_bytes()  # plain LF lines
    assert float(rows[2][1]) == 25.0 and float(rows[3][-1]) == pytest.approx(actions[2][1], abs=1e-6)
    # appending keeps one header
    proc = _run(
        code, json.dumps(good[0]) + "\n", ("--model", str(out / "policy.int8.onnx"), "--csv", str(csv_path))
    )
    assert proc.returncode == 0 and len(csv_path.read_text().splitlines()) == 5


def test_serve_bad_model(tmp_path: Path) -> None:
    code = RUN_SERVE
    proc = _run(code, "", ("--model", str(tmp_path / "missing.onnx")))
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1 and "not found" in proc.stderr
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not an onnx file")
    proc = _run(code, "", ("--model", str(bad)))
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1 and "invalid" in proc.stderr
