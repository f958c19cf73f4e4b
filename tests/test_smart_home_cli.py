"""SmartHome through the CLIs: train, evaluate metrics, export to ONNX (+ int8) and serve the export."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from cli_helpers import cli, last_json

ENV = "sbagents/SmartHome-v0"


def test_train_evaluate_export_serve(tmp_path: Path) -> None:
    # plumbing, not learning: 600 steps (100 of them updates after the entry's 500 learning_starts)
    result = cli("train", "--algo", "ddpg", "--env", ENV, "-n", "600", "-f", str(tmp_path), "--seed", "0",
                 "--verbose", "0", "--final-eval-episodes", "2")
    assert result.returncode == 0, result.stderr
    run_dir = tmp_path / "ddpg" / "sbagents_SmartHome-v0_1"
    assert (run_dir / "vecnormalize.npz").exists()
    report = last_json(cli("evaluate", "--algo", "ddpg", "--env", ENV, "-f", str(tmp_path), "-n", "2", "--json").stdout)
    assert set(report["metrics"]) == {"criterion_share", "mean_temp_error", "mean_light_error", "mean_energy"}
    share = report["metrics"]["criterion_share"]  # the mean of 2 episodes' shares of their 90 steps after step 10
    assert 0.0 <= share <= 1.0 and abs(180 * share - round(180 * share)) < 1e-6

    out = tmp_path / "export"
    exported = cli("export", "--algo", "ddpg", "--env", ENV, "-f", str(tmp_path), "--int8", "--out", str(out), "--json",
                   "--n-observations", "200")
    assert exported.returncode == 0, exported.stderr
    summary = last_json(exported.stdout)
    assert summary["parity_fp32"] <= 1e-4 and summary["parity_int8"] is not None
    assert set(summary["latency"]) == {"sb3_predict", "onnx", "onnx_int8"}
    assert (out / "policy.onnx").exists() and (out / "policy.int8.onnx").exists()
    meta = json.loads((out / "policy.json").read_text())
    assert meta["obs_names"][:2] == ["Temperature", "Light_Level"]

    obs = {"Temperature": 22.0, "Light_Level": 55.0, "Time": 3, "Preferred_Temp": 24.0, "Preferred_Light": 70.0}
    # a subprocess: the server reads its own stdin until EOF (servers stay in subprocesses)
    served = subprocess.run([sys.executable, "-m", "sbagents.serve", "--model", str(out / "policy.onnx")],
                            input=json.dumps(obs) + "\n[1, 2]\n", capture_output=True, text=True, timeout=60)
    assert served.returncode == 0, served.stderr
    action, error = (json.loads(line) for line in served.stdout.splitlines())
    assert len(action) == 2 and -1 <= action[0] <= 1 and -10 <= action[1] <= 10
    assert "error" in error
