"""The ``export`` benchmark on a tiny budget: train and export through the CLI, the section shows the report."""

from __future__ import annotations

import pytest

from benchmarks.suites import edge_export


@pytest.mark.slow  # trains and exports through the CLI: ~9 s
def test_export_benchmark_tiny_run_renders_the_cli_report() -> None:
    results = edge_export.run(["--n-timesteps", "300", "--n-observations", "50"])
    assert results["command"] == "python -m benchmarks run export --n-timesteps 300 --n-observations 50"
    assert results["commands"] == ["python -m sbagents.train --algo ddpg --env SmartHome-v0 --seed 0 -n 300",
                                   "python -m sbagents.export --algo ddpg --env SmartHome-v0 --int8 "
                                   "--n-observations 50"]
    rep = results["report"]
    assert rep["n_parity_observations"] == 50 and rep["parity_fp32"] < 1e-4
    assert 0 < rep["int8_bytes"] < rep["onnx_bytes"]
    section = edge_export.markdown(results)
    rows = [line for line in section.splitlines() if line.startswith("| ")][1:]
    assert [r.split(" | ")[0] for r in rows] == [
        "| SB3 `model.predict` (VecNormalize + torch)", "| `policy.onnx` (fp32)",
        "| `policy.int8.onnx` (onnxruntime `quantize_dynamic`)"]
    assert f"{rep['onnx_bytes']:,} B" in rows[1] and f"{rep['latency']['onnx']['p50_us']:.1f} us" in rows[1]
