"""``python -m sbagents.federated``: one SmartHome policy trained across homes with Flower (docs/federated.md).

Simulation by default (every home a Flower SuperNode on Ray, in this process); ``--deploy`` runs a real SuperLink
on localhost and waits for the homes (``python -m sbagents.federated.home --home I``, one process each).
"""

from __future__ import annotations

import argparse
import shlex
import sys

from sbagents.cli_common import ArgumentParser, run
from sbagents.core.zoo_config import parse_overrides
from sbagents.federated.settings import FEDERATED_ALGOS, STRATEGIES, FederatedSettings


def build_parser() -> ArgumentParser:
    """The ``federated`` argument parser."""
    d = FederatedSettings()
    p = ArgumentParser(prog="python -m sbagents.federated",
                       description="Train one policy across homes with federated learning (Flower).")
    p.add_argument("--env", default=d.env, help=f"env id (default {d.env})")
    p.add_argument("--algo", default=d.algo, help=f"{', '.join(FEDERATED_ALGOS)} (default {d.algo})")
    p.add_argument("--homes", type=int, default=d.homes, help=f"client homes, >= 2 (default {d.homes})")
    p.add_argument("--rounds", type=int, default=d.rounds, help=f"federated rounds (default {d.rounds})")
    p.add_argument("--local-steps", type=int, default=d.local_steps,
                   help=f"env steps each home trains per round (default {d.local_steps})")
    p.add_argument("--strategy", default=d.strategy, help=f"{', '.join(STRATEGIES)} (default {d.strategy})")
    p.add_argument("--proximal-mu", type=float, default=d.proximal_mu, help="fedprox: the proximal term's weight")
    p.add_argument("--dp-clip", type=float, default=d.dp_clip, help="dp-fedavg: L2 clip of each home's update")
    p.add_argument("--dp-noise", type=float, default=d.dp_noise, help="dp-fedavg: noise multiplier")
    p.add_argument("--dp-delta", type=float, default=d.dp_delta, help="dp-fedavg: delta of the reported epsilon")
    p.add_argument("--held-out", type=int, default=d.held_out,
                   help=f"held-out homes the server evaluates after each round (default {d.held_out})")
    p.add_argument("--eval-episodes", type=int, default=d.eval_episodes, help="episodes per held-out home")
    p.add_argument("--final-eval-episodes", type=int, default=10, help="episodes of the final evaluation")
    p.add_argument("--seed", type=int, default=d.seed, help="seed of the homes' draws and models")
    p.add_argument("-f", "--log-folder", default="logs", help="root of the run dirs (default: logs)")
    p.add_argument("-params", "--hyperparams", nargs="+", metavar="KEY:VALUE",
                   help="zoo config overrides for every home")
    p.add_argument("--personalize", type=int, default=None, metavar="HOME",
                   help="after training, fine-tune the global policy in client home HOME and report before/after")
    p.add_argument("--personal-steps", type=int, default=2000, help="fine-tuning budget (env steps)")
    p.add_argument("--deploy", action="store_true",
                   help="a real deployment on localhost: start a SuperLink and wait for the homes")
    p.add_argument("--port", type=int, default=8000, help="--deploy: the SuperLink's port (default 8000)")
    p.add_argument("-v", "--verbose", type=int, default=1, help="0: summary only; 2: Flower's own logs too")
    return p


def settings_from_args(args: argparse.Namespace) -> FederatedSettings:
    """The :class:`FederatedSettings` of the flags (env names resolved)."""
    from sbagents.core.env_names import resolve_env

    return FederatedSettings(
        algo=args.algo, env=resolve_env(args.env).env_id, homes=args.homes, rounds=args.rounds,
        local_steps=args.local_steps, strategy=args.strategy, proximal_mu=args.proximal_mu, dp_clip=args.dp_clip,
        dp_noise=args.dp_noise, dp_delta=args.dp_delta, seed=args.seed, held_out=args.held_out,
        eval_episodes=args.eval_episodes, hyperparams=parse_overrides(args.hyperparams))


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from sbagents.errors import UsageError
    from sbagents.federated.console import result_lines

    settings = settings_from_args(args)
    settings.validate()
    if args.personalize is not None and not 0 <= args.personalize < settings.homes:
        raise UsageError(f"--personalize {args.personalize}: homes are 0..{settings.homes - 1}")
    import torch

    torch.set_num_threads(1)
    from sbagents.federated.runner import federate

    command = "python -m sbagents.federated " + shlex.join(sys.argv[1:] if argv is None else argv)
    result = federate(settings, args.log_folder, deploy=args.deploy, port=args.port,
                      final_eval_episodes=args.final_eval_episodes, command=command, quiet=args.verbose <= 0,
                      verbose=args.verbose)
    personal = None
    if args.personalize is not None and not result.interrupted:
        from sbagents.federated.homes import client_homes
        from sbagents.federated.personal import personalize

        home = client_homes(settings.homes, settings.seed)[args.personalize]
        personal = personalize(result.run_dir, settings.algo, settings.env, home, args.personal_steps,
                               seed=settings.seed, log_folder=args.log_folder)
    print("\n".join(result_lines(result, personal)))
    return 130 if result.interrupted else 0


if __name__ == "__main__":
    run("python -m sbagents.federated", main)
