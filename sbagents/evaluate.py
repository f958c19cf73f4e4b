"""``python -m sbagents.evaluate``: evaluate a finished run (RL Zoo's ``enjoy``), SB3 or RLlib, or a baseline
policy on an env (``--policy random|scripted``, no run).

Parses the flags and calls :func:`sbagents.pipeline.backends.evaluate` or
:func:`sbagents.pipeline.evaluation.evaluate_baseline`.
"""

from __future__ import annotations

import argparse
import json

import torch

from sbagents.cli_common import ArgumentParser, add_run_arguments, run, run_ref
from sbagents.core.options import EvaluateOptions
from sbagents.core.run_dir import RunRef
from sbagents.errors import UsageError
from sbagents.pipeline.backends import evaluate
from sbagents.pipeline.console import format_evaluation
from sbagents.pipeline.evaluation import BASELINES, evaluate_baseline


def build_parser() -> ArgumentParser:
    """The ``evaluate`` argument parser."""
    p = ArgumentParser(prog="python -m sbagents.evaluate",
                       description="Evaluate a trained run (--algo, --env), or a baseline policy on an env "
                                   "(--policy, --env).")
    add_run_arguments(p, env_kwargs=True, required=False)
    p.add_argument("--policy", choices=BASELINES, default=None,
                   help="evaluate a baseline instead of a run: random (uniform actions; random legal moves in a "
                        "game) or scripted (the env's expert; a game's best built-in player), on the plain env")
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
    """Parse ``argv``, evaluate the run (or the baseline), print a table or JSON."""
    args = build_parser().parse_args(argv)
    torch.set_num_threads(1)
    ref, options = options_from_args(args)
    if args.policy is not None:
        if args.env is None or args.algo is not None:
            raise UsageError("--policy evaluates a baseline on --env ENV (no --algo: it names a run)")
        summary = evaluate_baseline(ref.env_ref(), args.policy, options, ref.env_kwargs)
    elif args.algo is None or args.env is None:
        raise UsageError("--algo and --env name the run to evaluate (or --policy random|scripted with --env)")
    else:
        summary = evaluate(ref, options)
    print(json.dumps(summary) if args.json else format_evaluation(summary))
    return 0


if __name__ == "__main__":
    run("python -m sbagents.evaluate", main)
