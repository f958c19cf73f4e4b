"""``python -m sbagents.export``: a finished run -> ``policy.onnx`` (+ int8), parity and latency report.

Parses the flags and calls :func:`sbagents.deploy.exporting.export_groups` (one policy per group of agents
for runs that train several).
"""

from __future__ import annotations

import json

import torch

from sbagents.cli_common import ArgumentParser, add_run_arguments, run, run_ref
from sbagents.deploy.exporting import export_groups, format_report


def build_parser() -> ArgumentParser:
    """The ``export`` argument parser."""
    p = ArgumentParser(prog="python -m sbagents.export", description="Export a trained policy to ONNX.")
    add_run_arguments(p, env_kwargs=True)
    p.add_argument("--int8", action="store_true", help="also write policy.int8.onnx (onnxruntime quantize_dynamic)")
    p.add_argument("--out", default=None, help="output folder (default: <run dir>/export)")
    p.add_argument("--n-observations", type=int, default=1000, help="observations for the parity check")
    p.add_argument("--json", action="store_true", help="print the report as one JSON object instead of text")
    return p


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv``, export, print the parity and latency report."""
    args = build_parser().parse_args(argv)
    torch.set_num_threads(1)
    reports = export_groups(run_ref(args), args.int8, args.out, args.n_observations)
    if len(reports) == 1:
        report = next(iter(reports.values()))
        print(json.dumps(report.to_dict()) if args.json else format_report(report))
    elif args.json:
        print(json.dumps({group: r.to_dict() for group, r in reports.items()}))
    else:
        print("\n".join(f"group {group}:\n" + format_report(r) for group, r in reports.items()))
    return 0 if all(r.parity_fp32 <= 1e-4 for r in reports.values()) else 1


if __name__ == "__main__":
    run("python -m sbagents.export", main)
