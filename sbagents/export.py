"""``python -m sbagents.export``: a finished run -> ``policy.onnx`` (+ int8), parity and latency report.

A thin shell over :func:`export`, which loads the run and calls :func:`sbagents.onnx_export.export_run`.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from stable_baselines3.common.vec_env import VecNormalize

from sbagents.callbacks.common import env_attr
from sbagents.cli import ArgumentParser, add_run_arguments, run
from sbagents.env_factory import make_eval_vec
from sbagents.env_ids import resolve_env
from sbagents.errors import UsageError
from sbagents.onnx_export import INT8_TOLERANCE, ExportReport, check_exportable, export_run
from sbagents.run_loading import load_run


def export(
    algo: str,
    env: str,
    log_folder: str | Path = "logs",
    exp_id: int = 0,
    load_best: bool = False,
    int8: bool = False,
    out: str | Path | None = None,
    n_observations: int = 1000,
    gym_packages: tuple[str, ...] = (),
) -> ExportReport:
    """Export run ``exp_id`` of ``algo`` on ``env`` to ONNX in ``out`` (default: ``<run dir>/export``).

    Parity is checked on ``n_observations`` observations recorded with the greedy policy on an env
    built exactly as in training (same env kwargs and wrappers, frozen VecNormalize statistics).
    """
    if n_observations < 1:
        raise UsageError(f"--n-observations must be >= 1, got {n_observations}")
    ref = resolve_env(env, gym_packages)
    loaded = load_run(algo, ref.env_id, log_folder, exp_id, load_best)
    exp = loaded.experiment
    if exp.frame_stack or exp.env_wrapper:
        raise UsageError(f"{ref.env_id} runs use env wrappers or frame stacking, which export cannot bake in")
    try:
        check_exportable(loaded.model)
    except TypeError as exc:
        raise UsageError(f"cannot export {algo}: {exc}") from None
    venv = make_eval_vec(exp, ref, 1, seed=0, stats_path=loaded.stats_path)
    vec_normalize = venv if isinstance(venv, VecNormalize) else None
    names = {k: tuple(v) if (v := env_attr(venv, k)) is not None else None for k in ("obs_names", "action_names")}
    try:
        return export_run(
            loaded.model, vec_normalize, out or loaded.run_dir / "export", int8, ref.env_id,
            obs_names=names["obs_names"], action_names=names["action_names"], env=venv,
            n_observations=n_observations,
        )
    finally:
        venv.close()


def build_parser() -> ArgumentParser:
    """The ``export`` argument parser."""
    p = ArgumentParser(prog="python -m sbagents.export", description="Export a trained policy to ONNX.")
    add_run_arguments(p)
    p.add_argument("--int8", action="store_true", help="also write policy.int8.onnx (onnxruntime quantize_dynamic)")
    p.add_argument("--out", default=None, help="output folder (default: <run dir>/export)")
    p.add_argument("--n-observations", type=int, default=1000, help="observations for the parity check")
    p.add_argument("--json", action="store_true", help="print the report as one JSON object instead of text")
    return p


def format_report(report: ExportReport) -> str:
    """The human-readable export report: files, parity, whether int8 is acceptable, latency."""
    lines = [f"wrote {report.onnx_path} ({report.onnx_bytes:,} bytes) and {report.sidecar_path}",
             f"parity fp32: max abs action difference {report.parity_fp32:.2e} over "
             f"{report.n_parity_observations} observations"]
    if report.int8_path is not None and report.int8_deviation is not None:
        limit = INT8_TOLERANCE[report.action_kind]
        if report.action_kind == "box":
            size = f"{100 * report.int8_deviation:.1f}% of the action range (limit {100 * limit:g}%)"
        else:
            size = f"a different action on {100 * report.int8_deviation:.1f}% of observations (limit {100 * limit:g}%)"
        verdict = "acceptable" if report.int8_acceptable else "NOT acceptable: keep the fp32 policy"
        lines.append(f"int8: {report.int8_path} ({report.int8_bytes:,} bytes), max abs action difference "
                     f"{report.parity_int8:.2e}, {size}: {verdict}")
    lines.append("latency (single observation): " + ", ".join(
        f"{name} p50 {row['p50_us']:.1f} us / p99 {row['p99_us']:.1f} us" for name, row in report.latency.items()))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv``, export, print the parity and latency report."""
    args = build_parser().parse_args(argv)
    torch.set_num_threads(1)
    report = export(
        args.algo, args.env, args.log_folder, args.exp_id, args.load_best, args.int8, args.out,
        args.n_observations, tuple(args.gym_packages),
    )
    print(json.dumps(report.to_dict()) if args.json else format_report(report))
    return 0 if report.parity_fp32 <= 1e-4 else 1


if __name__ == "__main__":
    run("python -m sbagents.export", main)
