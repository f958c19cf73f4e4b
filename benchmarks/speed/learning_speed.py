"""Learning steps per second of HER + SAC/TQC on the Kuka pick-and-place (and panda-gym's), beside the env's own rate.

One process, torch 1 thread. For each variant of the config entry (network size, ``n_envs``,
``train_freq``/``gradient_steps``) and each env, the model first fills ``learning_starts`` transitions, then
``--steps`` env steps are timed while it learns; the env alone (random actions, same env, same process) gives
the step-rate ceiling. Rounds are interleaved and the median is reported, so a load spike hits every variant alike.
The ratio column compares each variant with the first (SB3's default 256-256 networks, one gradient step per env
step), measured in the same command::

    python -m benchmarks run learning-speed --steps 2000 --rounds 2
    PANDA_VENV/bin/python -m benchmarks run learning-speed --panda ...   # PandaPickAndPlace-v3 beside

Learning steps/s is what a training run's wall time follows; gradient steps per env step (UTD) is what the
variant gives up for it: fewer updates per transition can cost sample efficiency, which only a learning run shows.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import torch as th
from stable_baselines3.common.env_util import make_vec_env

from benchmarks.harness import Benchmark
from benchmarks.report import BENCHMARKS_DIR, recorded_argv
from sbagents.algos import ALGOS
from sbagents.core.experiment import resolve
from sbagents.core.zoo_config import load_yaml

CONFIG = BENCHMARKS_DIR / "configs" / "kuka_pick.yml"
OURS = "sbagents/KukaPickAndPlace-v0"
PANDA = "PandaPickAndPlace-v3"
SECTION = "learning-speed"


@dataclass(frozen=True)
class Variant:
    """Overrides of the config entry.

    :param name: row label.
    :param algo: ``sac`` or ``tqc``.
    :param overrides: entry keys replaced (``n_envs``, ``train_freq``, ``gradient_steps``, ``policy_kwargs``, ...).
    """

    name: str
    algo: str = "sac"
    overrides: dict[str, Any] = field(default_factory=dict)

    def utd(self, entry: dict[str, Any]) -> float:
        """Gradient steps per env step."""
        merged = {**entry, **self.overrides}
        return float(merged["gradient_steps"]) / (float(merged["train_freq"]) * float(merged.get("n_envs", 1)))


SB3_NETS = {"policy_kwargs": {"net_arch": [256, 256]}}
ONE_ENV = {"n_envs": 1}
VARIANTS = [
    Variant("SB3 default nets 256-256, 1 env", overrides={**SB3_NETS, **ONE_ENV}),
    Variant("64-64, 1 env", overrides=ONE_ENV),
    Variant("64-64, 2 envs (shipped)"),
    Variant("64-64, 4 envs, 2 gradient steps", overrides={"n_envs": 4, "gradient_steps": 2}),
    Variant("64-64, 1 env, train_freq 2", overrides={**ONE_ENV, "train_freq": 2}),
    Variant("TQC 64-64, 2 envs", algo="tqc"),
]


def env_steps_per_second(env_id: str, n_steps: int, seed: int = 0) -> float:
    """Random-action env steps per second (resets included)."""
    env = gym.make(env_id)
    env.action_space.seed(seed)
    env.reset(seed=seed)
    start = time.perf_counter()
    for _ in range(n_steps):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
    rate = n_steps / (time.perf_counter() - start)
    env.close()
    return rate


def learning_steps_per_second(env_id: str, entry: dict[str, Any], variant: Variant, n_steps: int) -> float:
    """Env steps per second while learning, after ``learning_starts`` transitions."""
    merged = {**entry, **variant.overrides, "n_timesteps": n_steps}
    exp = resolve(variant.algo, env_id, merged, str(CONFIG))
    venv = make_vec_env(env_id, n_envs=exp.n_envs, seed=0)
    model = ALGOS[variant.algo].cls(exp.policy, venv, seed=0, device="cpu", **exp.algo_kwargs)
    warm = int(exp.algo_kwargs.get("learning_starts", 100)) + 200
    model.learn(warm)
    start = time.perf_counter()
    model.learn(n_steps, reset_num_timesteps=False)
    rate = (model.num_timesteps - warm) / (time.perf_counter() - start)
    venv.close()
    return rate


def measure(env_ids: list[str], steps: int, rounds: int) -> dict[str, dict[str, Any]]:
    """``{env_id: {"env": steps/s, variant name: steps/s}}``, medians over interleaved rounds."""
    config = load_yaml(CONFIG)
    samples: dict[str, dict[str, list[float]]] = {e: {} for e in env_ids}
    for _ in range(rounds):
        for env_id in env_ids:
            entry = {k: v for k, v in config[env_id].items() if k != "n_timesteps"}
            samples[env_id].setdefault("env", []).append(env_steps_per_second(env_id, 5 * steps))
            for v in VARIANTS:
                samples[env_id].setdefault(v.name, []).append(learning_steps_per_second(env_id, entry, v, steps))
                print(f"{env_id:32s} {v.name:36s} {samples[env_id][v.name][-1]:7.1f} steps/s", flush=True)
    return {e: {k: statistics.median(s) for k, s in by.items()} for e, by in samples.items()}


def utd_by_variant() -> dict[str, float]:
    """Gradient steps per env step of each of :data:`VARIANTS` in the config entry of :data:`OURS`."""
    entry = load_yaml(CONFIG)[OURS]
    return {v.name: v.utd(entry) for v in VARIANTS}


def table(rates: dict[str, dict[str, Any]], utd: dict[str, float]) -> str:
    """Markdown: one row per variant (the keys of ``utd``, in order), learning steps/s per env, ratio vs the first
    variant, gradient steps per env step (``utd``)."""
    envs = list(rates)
    head = "| variant | grad steps per env step | " + " | ".join(f"{e} steps/s (x first row)" for e in envs) + " |"
    lines = [head, "|---|---|" + "---|" * len(envs)]
    lines.append("| env alone, random actions | n/a | " + " | ".join(f"{rates[e]['env']:.0f}" for e in envs) + " |")
    first = next(iter(utd))
    for name, ratio in utd.items():
        cells = [f"{rates[e][name]:.0f} ({rates[e][name] / rates[e][first]:.2f}x)" for e in envs]
        lines.append(f"| {name} | {ratio:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def markdown(results: dict[str, Any]) -> str:
    """The ``learning-speed`` section of BENCHMARKS.md, from the results alone."""
    rates = results["rates"]
    command = results["command"]
    if PANDA in rates:
        command = command.replace("python ", "<panda-gym venv>/bin/python ", 1)
    return "\n".join([
        "## Learning steps per second (HER + SAC/TQC, pick-and-place)",
        "",
        f"Command: `{command}`; torch 1 thread, one process, "
        f"{results['steps']} timed learning steps per variant after `learning_starts`, median of {results['rounds']} "
        "interleaved rounds. "
        "The config is `benchmarks/configs/kuka_pick.yml` (HER, future strategy, batch 256); each row changes what "
        "it names. Learning steps/s is what a run's wall time follows; the ratio is against the first row, "
        "measured in the same command. Fewer gradient steps per env step can cost sample efficiency, which only "
        "the learning curves show (section kuka-pick-learning).",
        "",
        table(rates, results["utd"]),
    ])


def build_parser() -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run learning-speed``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=2000, help="timed learning steps per variant and round")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--panda", action="store_true", help="PandaPickAndPlace-v3 beside (needs panda-gym)")
    return parser


def run(argv: Sequence[str]) -> dict[str, Any]:
    """``python -m benchmarks run learning-speed [OPTIONS]``: measure; the results record the command."""
    args = build_parser().parse_args(list(argv))
    th.set_num_threads(1)
    import sbagents.envs  # noqa: F401  (registers the ids)

    env_ids = [OURS]
    if args.panda:
        import panda_gym  # noqa: F401

        env_ids.append(PANDA)
    rates = measure(env_ids, args.steps, args.rounds)
    return {"command": " ".join(["python -m benchmarks run", SECTION, *recorded_argv(list(argv))]),
            "steps": args.steps, "rounds": args.rounds, "utd": utd_by_variant(), "rates": rates}


BENCHMARKS = (
    Benchmark(name=SECTION, kind="speed", results="kuka_pick_learning_speed.json",
              summary="HER + SAC/TQC learning steps/s on the Kuka pick-and-place (and panda-gym's) per variant",
              run=run, render=markdown),
)
