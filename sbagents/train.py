"""``python -m sbagents.train``: parses the flags into option groups and calls :func:`sbagents.pipeline.backends.train`.

Flag names follow RL Zoo's ``train.py`` where they overlap. With no arguments it trains the book's first
agent (tabular Q-learning) on GridWorld and prints the learned path.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from typing import Any

from sbagents.openmp import passive_wait_policy

passive_wait_policy()  # before torch is imported (below): see sbagents.openmp

from sbagents.algos import ALGOS, capability_legend, capability_table  # noqa: E402
from sbagents.cli_common import ArgumentParser, run  # noqa: E402
from sbagents.core.backends import DEFAULT_BACKEND, backend_names  # noqa: E402
from sbagents.core.env_names import import_packages, sbagents_env_ids  # noqa: E402
from sbagents.core.extensions import registered_extensions, specs_from_args  # noqa: E402
from sbagents.core.options import EvalOptions, ExecOptions, OutputOptions, RllibOptions, Sb3Options, TrainSpec  # noqa: E402
from sbagents.core.zoo_config import parse_overrides  # noqa: E402
from sbagents.pipeline.backends import train  # noqa: E402
from sbagents.pipeline.console import train_summary_lines  # noqa: E402
from sbagents.visualize.showcase import describe_policy  # noqa: E402


def build_parser() -> ArgumentParser:
    """The ``train`` argument parser."""
    p = ArgumentParser(prog="python -m sbagents.train", description="Train an agent with a zoo config.")
    p.add_argument("--algo", default="qlearning", help="algorithm (see --list); default: qlearning")
    p.add_argument("--env", default="sbagents/GridWorld-v0", help="env id (see --list)")
    p.add_argument("-n", "--n-timesteps", type=int, default=None, help="override the config's n_timesteps")
    p.add_argument("-f", "--log-folder", default="logs", help="root of the run dirs (default: logs)")
    p.add_argument("--seed", type=int, default=-1, help="random seed (-1: draw one, recorded in summary.json)")
    p.add_argument("--eval-freq", type=int, default=None,
                   help="env steps between evaluations (default: n_timesteps/10, at most 25000; on-policy "
                        "algorithms: at least one rollout; <=0 disables)")
    p.add_argument("--eval-episodes", type=int, default=5, help="episodes per periodic evaluation")
    p.add_argument("--n-eval-envs", type=int, default=1, help="envs for periodic evaluation")
    p.add_argument("--final-eval-episodes", type=int, default=10, help="episodes of the final evaluation")
    p.add_argument("--save-freq", type=int, default=-1, help="checkpoint every N env steps (-1: never)")
    p.add_argument("-params", "--hyperparams", nargs="+", metavar="KEY:VALUE", help="override hyperparameters")
    p.add_argument("-conf", "--conf-file", default=None, help="zoo config file (default: zoo_configs/<algo>.yml)")
    p.add_argument("--env-kwargs", nargs="+", metavar="KEY:VALUE", help="env constructor keyword arguments")
    p.add_argument("--vec-env", default="auto", choices=["auto", "dummy", "subproc", "batched", "envpool"],
                   help="auto: batched numpy envs for GridWorld, TreasureHunt and mpe2.simple_spread_v3 "
                        "(discrete actions), EnvPool for Atari NoFrameskip-v4 ids when the atari extra is "
                        "installed, else dummy")
    p.add_argument("--device", default="auto", help="torch device (auto, cpu, cuda)")
    p.add_argument("--num-threads", type=int, default=1, help="torch threads (default 1; <=0 keeps torch's)")
    p.add_argument("-P", "--progress", action="store_true", default=None,
                   help="show the progress bar even when stderr is not a terminal")
    p.add_argument("-tb", "--tensorboard-log", default=None, help="TensorBoard log dir")
    p.add_argument("-i", "--trained-agent", default=None,
                   help="continue training this model .zip (with the replay_buffer.npz beside it when it was saved "
                        "at that model's step, and that checkpoint's own VecNormalize statistics)")
    p.add_argument("--trust-run", action="store_true",
                   help="the -i model and its files come from a source you trust: load pickles in them (older "
                        "runs' vecnormalize.pkl / replay_buffer.pkl; the zip as SB3 loads it instead of rebuilt "
                        "from plain data); see docs/security.md")
    p.add_argument("--gym-packages", nargs="+", default=[], help="packages to import that register envs")
    for extension in registered_extensions():  # trust callbacks, robust, constrained, DP training, yours
        extension.add_arguments(p.add_argument_group(extension.title))
    p.add_argument("--list", action="store_true", help="list registered envs and algorithms, then exit")
    p.add_argument("--log-interval", type=int, default=-1,
                   help="episodes (off-policy) or rollouts (on-policy) between logs; -1: 100 episodes / 1 rollout")
    p.add_argument("--verbose", type=int, default=1,
                   help="0 quiet, 1 progress bar + one line per evaluation (default), 2 also SB3's log tables")
    dist = p.add_argument_group("distributed (Ray RLlib; pip install 'sbagents[distributed]')")
    dist.add_argument("--backend", choices=backend_names(), default=DEFAULT_BACKEND,
                      help=f"training library (default {DEFAULT_BACKEND})")
    dist.add_argument("--num-env-runners", type=int, default=None, metavar="N",
                      help="RLlib env runner actors (default: the config's; 0 samples in the driver)")
    dist.add_argument("--address", default=None, metavar="ADDR",
                      help="Ray cluster to join (auto, host:6379 or ray://host:10001); default: a local Ray")
    return p


def options_from_args(args: argparse.Namespace, command: str) -> dict[str, Any]:
    """The option groups of :func:`sbagents.pipeline.backends.train` from the parsed flags (the extensions' specs
    under ``features``)."""
    return {
        "spec": TrainSpec(args.algo, args.env, n_timesteps=args.n_timesteps,
                          hyperparams=parse_overrides(args.hyperparams, "-params"), conf_file=args.conf_file,
                          env_kwargs=parse_overrides(args.env_kwargs, "--env-kwargs"),
                          gym_packages=tuple(args.gym_packages), trained_agent=args.trained_agent,
                          trust_run=args.trust_run),
        "output": OutputOptions(args.log_folder, tensorboard_log=args.tensorboard_log, save_freq=args.save_freq,
                                command=command),
        "evaluation": EvalOptions(eval_freq=args.eval_freq, eval_episodes=args.eval_episodes,
                                  n_eval_envs=args.n_eval_envs, final_eval_episodes=args.final_eval_episodes),
        "execution": ExecOptions(seed=args.seed, backend=args.backend, device=args.device,
                                 num_threads=args.num_threads, progress=args.progress, verbose=args.verbose),
        "sb3": Sb3Options(vec_env=args.vec_env, log_interval=args.log_interval),
        "rllib": RllibOptions(num_env_runners=args.num_env_runners, address=args.address),
        "features": specs_from_args(args),
    }


def import_user_packages(argv: list[str]) -> None:
    """Import the ``--gym-packages`` of ``argv`` before the parser is built: a package may register envs and training
    extensions (:func:`sbagents.register_extension`), whose flags the parser then has."""
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--gym-packages", nargs="+", default=[])
    known, _ = pre.parse_known_args(argv)
    import_packages(known.gym_packages)


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv``, train, print where the run went and its evaluation."""
    argv = sys.argv[1:] if argv is None else argv
    import_user_packages(argv)
    args = build_parser().parse_args(argv)
    if args.list:
        print("envs:  " + "  ".join(sbagents_env_ids()))
        print("algos: " + "  ".join(ALGOS))
        print("\nwhat each algorithm supports (the capabilities each feature declares):\n" + capability_table())
        print("\n" + "\n".join(capability_legend()))
        return 0
    command = "python -m sbagents.train " + shlex.join(argv)
    result = train(**options_from_args(args, command))
    lines = train_summary_lines(result.summary, result.run_dir, result.interrupted)
    if result.model is not None and not result.interrupted:
        text = describe_policy(result.model, result.experiment)
        lines[1:1] = [text] if text else []
    print("\n".join(lines))
    return 130 if result.interrupted else 0


if __name__ == "__main__":
    run("python -m sbagents.train", main)
