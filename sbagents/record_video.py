"""``python -m sbagents.record_video``: an mp4 of a trained agent (RL Zoo's ``record_video``), headless.

Parses the flags and calls :func:`sbagents.visualize.video.record_video`.
"""

from __future__ import annotations

import torch

from sbagents.cli_common import ArgumentParser, add_run_arguments, run, run_ref
from sbagents.visualize.video import record_video, sidecar_path


def build_parser() -> ArgumentParser:
    """The ``record_video`` argument parser."""
    p = ArgumentParser(prog="python -m sbagents.record_video", description="Record an mp4 of a trained agent.")
    add_run_arguments(p, env_kwargs=True)
    p.add_argument("-n", "--n-steps", type=int, default=1000, help="steps to record (default 1000)")
    p.add_argument("-o", "--output-folder", default=None, help="video folder (default: <run dir>/videos)")
    p.add_argument("--seed", type=int, default=0, help="seed of the recording env")
    p.add_argument("--fps", type=float, default=None, help="video frame rate (default: the env's render_fps)")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--deterministic", dest="deterministic", action="store_true", default=None,
                       help="greedy actions (the default, unless the run's config sets deterministic_eval: false)")
    group.add_argument("--stochastic", dest="deterministic", action="store_false", help="sample actions")
    return p


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv``, record the video, print its path (and its decisions sidecar's)."""
    args = build_parser().parse_args(argv)
    torch.set_num_threads(1)
    path = record_video(run_ref(args), args.n_steps, args.output_folder, args.seed, args.deterministic, args.fps)
    print(f"video: {path}")
    if sidecar_path(path).exists():
        print(f"decisions: {sidecar_path(path)}")
    return 0


if __name__ == "__main__":
    run("python -m sbagents.record_video", main)
