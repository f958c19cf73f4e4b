"""``python -m sbagents.export``: a finished run -> ``policy.onnx`` (+ int8), parity and latency report.

Parses the flags and calls :func:`sbagents.deploy.exporting.export`.
"""

from __future__ import annotations

import json

import torch

from sbagents.cli_common import ArgumentParser, add_run_arguments, run, run_ref
from sbagents.deploy.exporting import export, format_report


def build_parser() -> ArgumentParser:
    """The ``export`` argument parser."""
    p = ArgumentParser(prog="python -m sbagents.export", description="Export a trained policy to ONNX.")
    add_run_arguments(p)
    p.add_argument("--int8", action="store_true", help="also write policy.int8.onnx (onnxruntime quantize_dynamic)")
    p.add_argument("--out", default=None, help="output folder (default: <run dir>/export)")
    p.add_argument("--n-observations", type=int, default=1000, help="observations for the parity check")
    p.add_argument("--json", action="store_true", help="print the report as one JSON object instead of text")
    return p


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv``, export, print the parity and latency report."""
    args = build_parser().parse_args(argv)
    torch.set_num_threads(1)
    report = export(run_ref(args), args.int8, args.out, args.n_observations)
    print(json.dumps(report.to_dict()) if args.json else format_report(report))
    return 0 if report.parity_fp32 <= 1e-4 else 1


if __name__ == "__main__":
    run("python -m sbagents.export", main)
