"""``python -m sbagents.evaluate``: evaluate a finished run (RL Zoo's ``enjoy``), SB3 or RLlib.

Parses the flags and calls :func:`sbagents.pipeline.backends.evaluate`.
"""

from __future__ import annotations

import argparse
import json

import torch

from sbagents.cli_common import ArgumentParser, add_run_arguments, run, run_ref
from sbagents.core.options import EvaluateOptions
from sbagents.core.run_dir import RunRef
from sbagents.pipeline.backends import evaluate
from sbagents.pipeline.console import format_evaluation


def build_parser() -> ArgumentParser:
    """The ``evaluate`` argument parser."""
    p = ArgumentParser(prog="python -m sbagents.evaluate", description="Evaluate a trained run.")
    add_run_arguments(p, env_kwargs=True)
    p.add_argument("-n", "--n-episodes", type=int, default=10, help="episodes (games) to run (default 10)")
    p.add_argument("--render", action="store_true", help="print each state (text envs) or render in 'human' mode")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--deterministic", dest="deterministic", action="store_true", default=None,
                       help="greedy actions (the default, unless the run's config sets deterministic_eval: false)")
    group.add_argument("--stochastic", dest="deterministic", action="store_false", help="sample actions")
    p.add_argument("--seed", type=int, default=0, help="seed of the evaluation env")
    p.add_argument("--attack", default=None, metavar="SPEC",
                   help='observation attacks, e.g. "gaussian:0.05,0.1 pgd:0.05" (adversarial.csv/.png in the run dir)')
    p.add_argument("--fairness", default=None, metavar="KEYS",
                   help="info keys to bucket episodes by, e.g. preferred_temp,preferred_light")
    p.add_argument("--bins", type=int, default=3, help="buckets per fairness key")
    p.add_argument("--opponent", default=None, metavar="SPEC",
                   help="turn-based games: who plays the other seats: random, heuristic (connect four), minimax "
                        "(tic-tac-toe), a run dir, a model .zip, or module:function (observation, action_mask) -> "
                        "action; default: the run's self_play.eval_opponent. Seats alternate.")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object (last line)")
    return p


def options_from_args(args: argparse.Namespace) -> tuple[RunRef, EvaluateOptions]:
    """The arguments of :func:`sbagents.pipeline.backends.evaluate` from the parsed flags (all but ``--json``)."""
    options = EvaluateOptions(n_episodes=args.n_episodes, deterministic=args.deterministic, seed=args.seed,
                              render=args.render, attacks=args.attack, fairness=args.fairness, bins=args.bins,
                              opponent=args.opponent)
    return run_ref(args), options


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv``, evaluate the run, print a table or JSON."""
    args = build_parser().parse_args(argv)
    torch.set_num_threads(1)
    summary = evaluate(*options_from_args(args))
    print(json.dumps(summary) if args.json else format_evaluation(summary))
    return 0


if __name__ == "__main__":
    run("python -m sbagents.evaluate", main)
