"""``python -m sbagents.collect``: record episodes of a baseline (``--policy random|scripted``) or of a finished run
(``--algo ALGO -f LOGS [--exp-id K]``) on an env, or read them from a run's transparency log (``--from-log PATH``),
into a Minari dataset (``--dataset namespace/name-vN``; the ``data`` extra).

Parses the flags and calls :func:`sbagents.pipeline.collecting.collect`.
"""

from __future__ import annotations

from pathlib import Path

import torch

from sbagents.cli_common import ArgumentParser, add_run_arguments, run, run_ref
from sbagents.errors import UsageError
from sbagents.pipeline.collecting import CollectOptions, collect
from sbagents.pipeline.evaluation import BASELINES


def build_parser() -> ArgumentParser:
    """The ``collect`` argument parser."""
    p = ArgumentParser(prog="python -m sbagents.collect",
                       description="Record episodes of a baseline policy or of a finished run into a Minari dataset.")
    add_run_arguments(p, required=False, load_best=True, env_kwargs=True)
    p.add_argument("--policy", choices=BASELINES, default=None,
                   help="who acts instead of a run: random (uniform actions) or scripted (the env's expert)")
    p.add_argument("--from-log", default=None, metavar="PATH",
                   help="read the episodes from a run's transparency log (train --transparency-log) of --env")
    p.add_argument("--episodes", type=int, default=None,
                   help="episodes to record (required but with --from-log, where it caps the complete episodes read)")
    p.add_argument("--dataset", required=True, metavar="ID",
                   help="dataset id namespace/name-vN, written under MINARI_DATASETS_PATH (default ~/.minari/datasets)")
    p.add_argument("--seed", type=int, default=0, help="reset seed of the first episode (episode i: seed + i)")
    p.add_argument("--ref-episodes", type=int, default=10,
                   help="episodes of random play and of the expert that set the dataset's reference scores (envs "
                        "with a scripted expert; 0: none)")
    p.add_argument("--group", default=None, metavar="NAME",
                   help="a team of several groups: record this group's agents (every group acts; a baseline plays "
                        "one policy per group)")
    p.add_argument("--opponent", default=None, metavar="SPEC",
                   help="a turn-based game: who plays the other seats (as evaluate --opponent; default random)")
    p.add_argument("-P", "--progress", action="store_true", default=None, help="show a progress bar")
    return p


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv``, record the episodes, print where the dataset went."""
    args = build_parser().parse_args(argv)
    torch.set_num_threads(1)
    if args.env is None:
        raise UsageError("--env names the env to record")
    ref = run_ref(args)
    options = CollectOptions(args.episodes, args.dataset, args.seed, args.ref_episodes, args.progress, args.group,
                             args.opponent)
    if sum(given is not None for given in (args.policy, args.algo, args.from_log)) > 1:
        raise UsageError("--policy records a baseline, --algo names a run, --from-log reads a log: give one of them")
    if args.policy is not None:
        path, count = collect(options, env=ref.env_ref(), policy=args.policy, env_kwargs=ref.env_kwargs)
    elif args.algo is not None:
        path, count = collect(options, run=ref)
    elif args.from_log is not None:
        path, count = collect(options, env=ref.env_ref(), log=Path(args.from_log), env_kwargs=ref.env_kwargs)
    else:
        raise UsageError("who acts: --policy random|scripted, a run with --algo ALGO (-f LOGS, --exp-id K), or "
                         "--from-log PATH")
    print(f"dataset {args.dataset}: {count} episodes in {path}")
    return 0


if __name__ == "__main__":
    run("python -m sbagents.collect", main)
