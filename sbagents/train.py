"""``python -m sbagents.train``: parses the flags into option groups and calls :func:`sbagents.pipeline.backends.train`.

Flag names follow RL Zoo's ``train.py`` where they overlap. With no arguments it trains the book's first
agent (tabular Q-learning) on GridWorld and prints the learned path.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from typing import Any

from sbagents.algos import ALGOS
from sbagents.cli_common import ArgumentParser, run
from sbagents.core.env_names import sbagents_env_ids
from sbagents.core.options import EvalOptions, ExecOptions, OutputOptions, TrainSpec
from sbagents.core.zoo_config import parse_overrides
from sbagents.errors import UsageError
from sbagents.pipeline.backends import train
from sbagents.pipeline.console import train_summary_lines
from sbagents.pipeline.trust import TrustOptions, trust_summary_lines
from sbagents.private.options import PrivacyOptions
from sbagents.visualize.showcase import describe_policy


def build_parser() -> ArgumentParser:
    """The ``train`` argument parser."""
    p = ArgumentParser(prog="python -m sbagents.train", description="Train an agent with a zoo config.")
    p.add_argument("--algo", default="qlearning", help="algorithm (see --list); default: qlearning")
    p.add_argument("--env", default="sbagents/GridWorld-v0", help="env id (see --list)")
    p.add_argument("-n", "--n-timesteps", type=int, default=None, help="override the config's n_timesteps")
    p.add_argument("-f", "--log-folder", default="logs", help="root of the run dirs (default: logs)")
    p.add_argument("--seed", type=int, default=-1, help="random seed (-1: draw one, recorded in summary.json)")
    p.add_argument("--eval-freq", type=int, default=None,
                   help="env steps between evaluations (default: n_timesteps/10, at most 25000; <=0 disables)")
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
                   help="continue training this model .zip (with the replay_buffer.npz beside it, if any)")
    p.add_argument("--trust-run", action="store_true",
                   help="the -i model and its files come from a source you trust: load pickles in them (older "
                        "runs' vecnormalize.pkl / replay_buffer.pkl, model entries beyond plain data); see "
                        "docs/security.md")
    p.add_argument("--save-replay-buffer", action="store_true",
                   help="off-policy: keep the replay buffer in the run dir (replay_buffer.npz, replaced at each "
                        "checkpoint and at the end, also after Ctrl-C) so that -i continues with it")
    p.add_argument("--gym-packages", nargs="+", default=[], help="packages to import that register envs")
    trust = p.add_argument_group("trust (sbagents.callbacks)")
    trust.add_argument("--transparency-log", nargs="?", const="", default=None, metavar="PATH",
                       help="CSV of every decision (default <run dir>/transparency.csv; .csv.gz compresses)")
    trust.add_argument("--transparency-format", choices=["full", "book"], default="full",
                       help="full: every obs/action/info column; book: the book's header (SmartHome)")
    trust.add_argument("--safety", action="store_true", help="count safety violations (safety.json, TensorBoard)")
    trust.add_argument("--cost-limit", type=float, default=None,
                       help="stop when the mean episode cost passes X (with --constraint: the limit trained for)")
    trust.add_argument("--constraint", choices=["lagrangian", "pid"], default=None,
                       help="train under --cost-limit: PPO-Lagrangian (ppo) or SAC-Lagrangian (sac) with a cost "
                            "critic and a Lagrange (or PID) multiplier, settings from the entry's constraint_kwargs; "
                            "safety.json records its history")
    trust.add_argument("--max-violations", type=int, default=None, help="stop after N violations")
    trust.add_argument("--adversarial-eval", default=None, metavar="SPEC",
                       help='attacks evaluated during training, e.g. "gaussian:0.05,0.1 fgsm:0.01,0.05"')
    trust.add_argument("--fairness", default=None, metavar="KEYS",
                       help="info keys to bucket episodes by, e.g. object_scale,object_mass")
    trust.add_argument("--bins", type=int, default=3, help="buckets per fairness key")
    robust = p.add_argument_group("robust training (sbagents.robust)")
    robust.add_argument("--robust", default=None, metavar="SPEC",
                        help="METHOD:EPS[,KEY=VALUE...]: sa (state-adversarial regularizer; ddpg, td3; keys kappa, "
                             "steps, qdrop, ramp), adv (adversarial rollouts; ddpg, td3, sac; keys attack, share, "
                             "ramp) or sa+adv; eps in the attacks' units, ramped up over the first half of training")
    private = p.add_argument_group("privacy (DP-SGD with Opacus; ddpg, td3, sac, ppo, a2c; "
                                   "pip install 'sbagents[private]')")
    private.add_argument("--dp-epsilon", type=float, default=None, metavar="E",
                         help="train with (E, delta)-DP per transition: noise calibrated to the run's draws (ppo, "
                              "a2c: to one rollout's; with --dp-noise: stop before passing E)")
    private.add_argument("--dp-delta", type=float, default=None, metavar="D",
                         help="delta, below 1 / the transitions trained on (default 1e-5)")
    private.add_argument("--dp-clip", type=float, default=None, metavar="C",
                         help="per-transition gradient clipping norm (default 1.0)")
    private.add_argument("--dp-noise", type=float, default=None, metavar="SIGMA",
                         help="noise multiplier instead of a calibrated one (epsilon is reported)")
    p.add_argument("--list", action="store_true", help="list registered envs and algorithms, then exit")
    p.add_argument("--log-interval", type=int, default=-1,
                   help="episodes (off-policy) or rollouts (on-policy) between logs; -1: 100 episodes / 1 rollout")
    p.add_argument("--verbose", type=int, default=1,
                   help="0 quiet, 1 progress bar + one line per evaluation (default), 2 also SB3's log tables")
    dist = p.add_argument_group("distributed (Ray RLlib, PettingZoo envs; pip install 'sbagents[distributed]')")
    dist.add_argument("--backend", choices=["sb3", "rllib"], default="sb3", help="training library (default sb3)")
    dist.add_argument("--num-env-runners", type=int, default=None, metavar="N",
                      help="RLlib env runner actors (default: the config's; 0 samples in the driver)")
    dist.add_argument("--address", default=None, metavar="ADDR",
                      help="Ray cluster to join (auto, host:6379 or ray://host:10001); default: a local Ray")
    return p


def privacy_from_args(args: argparse.Namespace) -> PrivacyOptions:
    """The ``--dp-*`` flags; ``--dp-delta`` / ``--dp-clip`` alone are refused (they would do nothing)."""
    if args.dp_epsilon is None and args.dp_noise is None and (args.dp_delta is not None or args.dp_clip is not None):
        raise UsageError("--dp-delta and --dp-clip apply to DP training: add --dp-epsilon E or --dp-noise SIGMA")
    defaults = PrivacyOptions()
    return PrivacyOptions(args.dp_epsilon, defaults.delta if args.dp_delta is None else args.dp_delta,
                          defaults.clip if args.dp_clip is None else args.dp_clip, args.dp_noise)


def options_from_args(args: argparse.Namespace, command: str) -> dict[str, Any]:
    """The option groups of :func:`sbagents.pipeline.backends.train` from the parsed flags."""
    return {
        "spec": TrainSpec(args.algo, args.env, args.n_timesteps, parse_overrides(args.hyperparams, "-params"),
                          args.conf_file, parse_overrides(args.env_kwargs, "--env-kwargs"),
                          tuple(args.gym_packages), args.trained_agent, args.robust, args.constraint,
                          trust_run=args.trust_run),
        "output": OutputOptions(args.log_folder, args.tensorboard_log, args.save_freq, command,
                                args.save_replay_buffer),
        "evaluation": EvalOptions(args.eval_freq, args.eval_episodes, args.n_eval_envs, args.final_eval_episodes),
        "execution": ExecOptions(args.seed, args.backend, args.vec_env, args.device, args.num_threads, args.progress,
                                 args.verbose, args.log_interval, args.num_env_runners, args.address),
        "trust": TrustOptions(args.transparency_log, args.safety, args.cost_limit, args.max_violations,
                              args.adversarial_eval, args.fairness, args.bins,
                              book_header=args.transparency_format == "book"),
        "privacy": privacy_from_args(args),
    }


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv``, train, print where the run went and its evaluation."""
    args = build_parser().parse_args(argv)
    if args.list:
        print("envs:  " + "  ".join(sbagents_env_ids()))
        print("algos: " + "  ".join(ALGOS))
        return 0
    command = "python -m sbagents.train " + shlex.join(sys.argv[1:] if argv is None else argv)
    result = train(**options_from_args(args, command))
    lines = train_summary_lines(result.summary, result.run_dir, result.interrupted)
    if result.model is not None and not result.interrupted:
        text = describe_policy(result.model, result.experiment)
        lines[1:1] = [text] if text else []
    print("\n".join([*lines, *trust_summary_lines(result.trust)]))
    return 130 if result.interrupted else 0


if __name__ == "__main__":
    run("python -m sbagents.train", main)
