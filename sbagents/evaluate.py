"""``python -m sbagents.evaluate``: a thin argparse shell over :func:`sbagents.evaluation.evaluate` (RL Zoo's enjoy)."""

from __future__ import annotations

import json
from typing import Any

import torch

from sbagents.cli import ArgumentParser, add_run_arguments, run
from sbagents.evaluation import evaluate


def build_parser() -> ArgumentParser:
    """The ``evaluate`` argument parser."""
    p = ArgumentParser(prog="python -m sbagents.evaluate", description="Evaluate a trained run.")
    add_run_arguments(p)
    p.add_argument("-n", "--n-episodes", type=int, default=10, help="episodes to run (default 10)")
    p.add_argument("--render", action="store_true", help="render in 'human' mode while evaluating")
    p.add_argument("--stochastic", action="store_true", help="sample actions instead of the greedy policy")
    p.add_argument("--seed", type=int, default=0, help="seed of the evaluation env")
    p.add_argument("--attack", default=None, metavar="SPEC",
                   help='observation attacks, e.g. "gaussian:0.05,0.1 pgd:0.05" (adversarial.csv/.png in the run dir)')
    p.add_argument("--fairness", default=None, metavar="KEYS",
                   help="info keys to bucket episodes by, e.g. preferred_temp,preferred_light")
    p.add_argument("--bins", type=int, default=3, help="buckets per fairness key")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object (last line)")
    return p


def format_table(summary: dict[str, Any]) -> str:
    """A small two-column text table of an evaluation summary."""
    rows = [(k, summary[k]) for k in ("env", "algo", "n_episodes", "mean_return", "std_return", "mean_length",
                                      "success_rate")]
    rows += [(f"metrics.{k}", v) for k, v in summary["metrics"].items()]
    rows += [(f"attack.{r['label']}.mean_return", r["mean_return"]) for r in summary.get("adversarial", [])]
    if "fairness" in summary:
        fair = summary["fairness"]
        rows += [("fairness.metric", fair["metric"]), ("fairness.worst_bucket_value", fair["worst"]["value"]),
                 ("fairness.gap", fair["gap"])]
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v:.4g}" if isinstance(v, float) else f"{k:<{width}}  {v}" for k, v in rows)


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv``, evaluate the run, print a table or JSON."""
    args = build_parser().parse_args(argv)
    torch.set_num_threads(1)
    summary = evaluate(
        args.algo, args.env, log_folder=args.log_folder, exp_id=args.exp_id, load_best=args.load_best,
        n_episodes=args.n_episodes, deterministic=not args.stochastic, seed=args.seed, render=args.render,
        gym_packages=tuple(args.gym_packages), attacks=args.attack, fairness=args.fairness, bins=args.bins,
    )
    print(json.dumps(summary) if args.json else format_table(summary))
    return 0


if __name__ == "__main__":
    run("python -m sbagents.evaluate", main)
