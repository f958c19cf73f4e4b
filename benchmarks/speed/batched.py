"""Env stepping and PPO training speed: reference VecEnvs vs the batched numpy VecEnvs (``sbagents.batched``).

Measured for ``sbagents/GridWorld-v0``, ``treasure_hunt_v0``, ``mpe2.simple_spread_v3`` (discrete actions) and
``pettingzoo.sisl.pursuit_v5`` (the zoo config's env kwargs):

- env steps/s with random actions, resets included: one plain env (Python loop), the reference VecEnv
  of 64 copies (``make_vec_env`` DummyVecEnv / ``ParameterSharingVecEnv``, the ``policies: shared`` team VecEnv)
  and the batched VecEnv of 64;
- PPO training fps (``model.learn`` only, torch 1 thread) with the zoo config's hyperparameters, on the
  reference and on the batched VecEnv, at the config's ``n_envs`` and at 64.

Steps are counted as VecEnv transitions: for the multi-agent envs one transition is one agent's step (an env
step of the 3-agent team is 3 transitions), which is also what SB3's fps counts. Rounds are interleaved
and medians reported, so a load spike on the shared machine hits every variant alike.

    python -m benchmarks run speed [--rounds 3] [--envs ENV_ID ...]
    python -m benchmarks run speed --quick    # smoke run: a quarter of the steps, PPO one round

Results: ``benchmarks/results/speed.json``; section ``speed`` of ``BENCHMARKS.md``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecEnv

import sbagents  # noqa: F401  (registers the Gymnasium ids)
from benchmarks.harness import Benchmark
from benchmarks.report import machine_info, recorded_argv
from benchmarks.speed.noop_vec_env import NoOpVecEnv
from sbagents.batched import make_batched_vec_env
from sbagents.core.env_names import resolve_env
from sbagents.core.experiment import Experiment, build_experiment
from sbagents.core.options import TrainSpec
from sbagents.envs.treasure_hunt_v0 import parallel_env
from sbagents.multiagent.parameter_sharing import make_parameter_sharing_vec_env

SIMPLE_SPREAD = "mpe2.simple_spread_v3"
PURSUIT = "pettingzoo.sisl.pursuit_v5"
ENV_IDS: tuple[str, ...] = ("sbagents/GridWorld-v0", "treasure_hunt_v0", SIMPLE_SPREAD, PURSUIT)
MULTI_AGENT: tuple[str, ...] = ("treasure_hunt_v0", SIMPLE_SPREAD, PURSUIT)
N_ENVS = 64
WARMUP_STEPS = 20  # untimed VecEnv steps before each stepping measurement
#: Steps per measurement (plain env steps, reference and batched VecEnv steps): ~0.3-1.5 s each on this machine.
STEPS: dict[str, tuple[int, int, int]] = {
    "sbagents/GridWorld-v0": (50_000, 1000, 20_000),
    "treasure_hunt_v0": (50_000, 200, 3000),
    SIMPLE_SPREAD: (2000, 50, 2000),  # mpe2's step is slow: ~2,500 plain env steps/s
    PURSUIT: (500, 10, 1000),  # pursuit's step is slower: ~250 plain env steps/s
}


def parallel_env_fn(env_id: str) -> Callable[..., Any]:
    """``parallel_env`` of a multi-agent env of :data:`MULTI_AGENT`."""
    if env_id == SIMPLE_SPREAD:
        from mpe2 import simple_spread_v3

        return simple_spread_v3.parallel_env  # type: ignore[no-any-return]
    if env_id == PURSUIT:
        from pettingzoo.sisl import pursuit_v5

        return pursuit_v5.parallel_env  # type: ignore[no-any-return]
    return parallel_env


def reference_vec_env(env_id: str, n_envs: int, seed: int, env_kwargs: dict[str, Any]) -> VecEnv:
    """The VecEnv the project used before the batched envs (DummyVecEnv / ParameterSharingVecEnv)."""
    if env_id in MULTI_AGENT:
        return make_parameter_sharing_vec_env(parallel_env_fn(env_id), n_envs, seed, env_kwargs)
    return make_vec_env(env_id, n_envs=n_envs, seed=seed, env_kwargs=env_kwargs)


def ppo_experiment(env_id: str) -> Experiment:
    """The shipped PPO zoo entry of ``env_id``."""
    return build_experiment(TrainSpec("ppo", env_id), resolve_env(env_id))


def zoo_env_kwargs(env_id: str) -> dict[str, Any]:
    """``env_kwargs`` of the PPO zoo entry of ``env_id``."""
    return dict(ppo_experiment(env_id).env_kwargs)


def single_env_rate(env_id: str, env_kwargs: dict[str, Any], n_steps: int, seed: int = 0) -> float:
    """Transitions/s of one plain env stepped in a Python loop (reset at episode ends)."""
    rng = np.random.default_rng(seed)
    if env_id in MULTI_AGENT:
        env = parallel_env_fn(env_id)(**env_kwargs)
        env.reset(seed=seed)
        agents = list(env.possible_agents)
        actions = rng.integers(0, 5, size=(n_steps, len(agents))).tolist()
        start = time.perf_counter()
        for row in actions:
            _, _, term, trunc, _ = env.step(dict(zip(agents, row, strict=True)))
            if term[agents[0]] or trunc[agents[0]]:
                env.reset()
        env.close()
        return n_steps * len(agents) / (time.perf_counter() - start)
    genv = gym.make(env_id, **env_kwargs)
    genv.reset(seed=seed)
    acts = rng.integers(0, 4, size=n_steps).tolist()
    start = time.perf_counter()
    for a in acts:
        _, _, terminated, truncated, _ = genv.step(a)
        if terminated or truncated:
            genv.reset()
    return n_steps / (time.perf_counter() - start)


def vec_env_rate(vec: VecEnv, n_steps: int, seed: int = 0) -> float:
    """Transitions/s of ``n_steps`` VecEnv steps with random actions (auto-resets included), timed after
    :data:`WARMUP_STEPS` untimed ones."""
    n_actions = int(vec.action_space.n)  # type: ignore[attr-defined]
    actions = np.random.default_rng(seed).integers(0, n_actions, size=(WARMUP_STEPS + n_steps, vec.num_envs))
    vec.reset()
    for a in actions[:WARMUP_STEPS]:  # first calls load compiled kernels and warm caches
        vec.step(a)
    start = time.perf_counter()
    for a in actions[WARMUP_STEPS:]:
        vec.step(a)
    rate = n_steps * vec.num_envs / (time.perf_counter() - start)
    vec.close()
    return rate


def make_vec_kind(env_id: str, kind: str, n_envs: int, seed: int, env_kwargs: dict[str, Any]) -> VecEnv:
    """``reference``, ``batched`` or ``noop`` (:class:`benchmarks.speed.noop_vec_env.NoOpVecEnv`: the ceiling)."""
    if kind == "reference":
        return reference_vec_env(env_id, n_envs, seed, env_kwargs)
    batched = make_batched_vec_env(env_id, n_envs, seed, env_kwargs, None)
    return NoOpVecEnv(batched) if kind == "noop" else batched


def ppo_kwargs(env_id: str, n_envs: int) -> dict[str, Any]:
    """The zoo config's PPO keyword arguments for ``n_envs`` env copies.

    At the config's own ``n_envs`` they are the config's. At another ``n_envs`` the minibatch size is scaled
    with the rollout so that every rollout is still split into the config's number of minibatches
    (CleanRL's ``num_minibatches`` convention): scaling out the envs then scales the data per gradient step,
    not the number of gradient steps per transition.
    """
    exp = ppo_experiment(env_id)
    kwargs = dict(exp.algo_kwargs)
    if n_envs != exp.n_envs:
        kwargs["batch_size"] = max(1, kwargs.get("batch_size", 64) * n_envs // exp.n_envs)
    return kwargs


def ppo_fps(env_id: str, vec_kind: str, n_envs: int, min_steps: int = 24_000, seed: int = 0) -> float:
    """PPO training fps (``learn`` only) with the zoo hyperparameters (:func:`ppo_kwargs`) on ``n_envs`` copies.

    Times whole rollouts, at least two and at least ``min_steps`` transitions, after one untimed rollout.
    """
    torch.set_num_threads(1)
    exp = ppo_experiment(env_id)
    vec = make_vec_kind(env_id, vec_kind, n_envs, seed, exp.env_kwargs)
    model = PPO(exp.policy, vec, seed=seed, verbose=0, **ppo_kwargs(env_id, n_envs))
    rollout = model.n_steps * vec.num_envs
    steps = max(2, -(-min_steps // rollout)) * rollout
    model.learn(rollout)  # warm-up rollout and update, not timed
    start = time.perf_counter()
    model.learn(steps, reset_num_timesteps=False)
    fps = steps / (time.perf_counter() - start)
    vec.close()
    return fps


def _median_rounds(fns: dict[str, Callable[[], float]], rounds: int,
                   samples: dict[str, list[float]] | None = None) -> dict[str, float]:
    """Run the measurements interleaved ``rounds`` times; their medians (each round's values appended to
    ``samples`` when given, so the section can show the per-round ratios' range)."""
    samples = {} if samples is None else samples
    for key in fns:
        samples.setdefault(key, [])
    for _ in range(rounds):
        for key, fn in fns.items():
            samples[key].append(fn())
    return {k: statistics.median(samples[k]) for k in fns}


def ratio_range(rounds: dict[str, list[float]] | None, num: str, den: str) -> str:
    """`` (min-max)`` of the per-round ratios ``num / den`` (paired by round); ``""`` without rounds."""
    if not rounds or len(rounds.get(num, [])) < 2:
        return ""
    ratios = [a / b for a, b in zip(rounds[num], rounds[den], strict=True)]
    return f" ({min(ratios):.2f}-{max(ratios):.2f})"


def measure(rounds: int = 3, quick: bool = False, env_ids: Sequence[str] = ENV_IDS) -> dict[str, Any]:
    """Measure every figure of ``env_ids``; returns a JSON-able dict (``machine`` + one entry per env id)."""
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    started = time.perf_counter()
    results: dict[str, Any] = {"machine": machine_info(), "envs": {}}
    scale = 0.25 if quick else 1.0
    for env_id in env_ids:
        kwargs = zoo_env_kwargs(env_id)
        n_cfg = ppo_experiment(env_id).n_envs
        single_steps, ref_steps, batched_steps = STEPS[env_id]
        fns: dict[str, Callable[[], float]] = {
            "single": partial(single_env_rate, env_id, kwargs, int(single_steps * scale)),
            "reference": lambda e=env_id, k=kwargs, n=int(ref_steps * scale): vec_env_rate(  # type: ignore[misc]
                reference_vec_env(e, N_ENVS, 0, k), n
            ),
            "batched": lambda e=env_id, k=kwargs, n=int(batched_steps * scale): vec_env_rate(  # type: ignore[misc]
                make_batched_vec_env(e, N_ENVS, 0, k, None), n
            ),
            "noop": lambda e=env_id, k=kwargs, n=int(batched_steps * scale): vec_env_rate(  # type: ignore[misc]
                make_vec_kind(e, "noop", N_ENVS, 0, k), n
            ),
        }
        env_rounds: dict[str, list[float]] = {}
        env_rates = _median_rounds(fns, rounds, env_rounds)
        ppo: dict[str, float] = {}
        ppo_rounds: dict[str, list[float]] = {}
        for n_envs in sorted({n_cfg, N_ENVS}):
            ppo_fns: dict[str, Callable[[], float]] = {
                kind: partial(ppo_fps, env_id, kind, n_envs, 6_000 if quick else 48_000)
                for kind in ("reference", "batched", "noop")
            }
            samples: dict[str, list[float]] = {}
            rates = _median_rounds(ppo_fns, 1 if quick else rounds, samples)
            ppo.update({f"{kind}_{n_envs}": v for kind, v in rates.items()})
            ppo_rounds.update({f"{kind}_{n_envs}": v for kind, v in samples.items()})
        batch = {str(n): ppo_kwargs(env_id, n).get("batch_size", 64) for n in sorted({n_cfg, N_ENVS})}
        results["envs"][env_id] = {"env_kwargs": kwargs, "config_n_envs": n_cfg, "steps_per_s": env_rates,
                                   "ppo_fps": ppo, "ppo_batch_size": batch,
                                   "steps_per_s_rounds": env_rounds, "ppo_fps_rounds": ppo_rounds}
    results["machine"]["load_before"] = [round(x, 2) for x in load_before]
    results["machine"]["load_after"] = [round(x, 2) for x in os.getloadavg()]
    results["seconds"] = round(time.perf_counter() - started, 1)
    return results




def _fmt(x: float) -> str:
    return f"{x:,.0f}"


def markdown(results: dict[str, Any]) -> str:
    """The ``speed`` section (tables + machine line) from the results alone."""
    m = results["machine"]
    lines = [
        "## Batched VecEnvs: env and PPO speed",
        "",
        f"Machine: {m['cpu']}, {m['cores']} cores, Python {m['python']}, numpy {m['numpy']}, "
        f"torch {m['torch']} (1 thread), SB3 {m['stable_baselines3']}; {m['date']}; "
        f"load average before/after {m['load_before'][0]} / {m['load_after'][0]} "
        f"(shared machine). Command: `{results['command']}`.",
        "",
        "Env transitions/s with random actions (resets included; TreasureHunt, simple spread and pursuit: one "
        "transition = one agent step):",
        "",
        f"| env | single env | reference x{N_ENVS} | batched x{N_ENVS} | batched / reference | no-op x{N_ENVS} "
        "| no-op / reference (ceiling) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for env_id, r in results["envs"].items():
        s = r["steps_per_s"]
        span = ratio_range(r.get("steps_per_s_rounds"), "batched", "reference")
        lines.append(f"| {env_id} | {_fmt(s['single'])} | {_fmt(s['reference'])} | {_fmt(s['batched'])} | "
                     f"{s['batched'] / s['reference']:.1f}x{span} | "
                     f"{_fmt(s['noop'])} | {s['noop'] / s['reference']:.1f}x |")
    lines += [
        "",
        "PPO training fps (`model.learn` only, zoo hyperparameters, torch 1 thread). At an `n_envs` other than "
        "the config's, `batch_size` is scaled with the rollout so each rollout keeps the config's number of "
        "minibatches:",
        "",
        "| env | n_envs | batch_size | reference | batched | batched / reference | no-op | no-op / reference "
        "(ceiling) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for env_id, r in results["envs"].items():
        for n in sorted({r["config_n_envs"], N_ENVS}):
            ref, bat = r["ppo_fps"][f"reference_{n}"], r["ppo_fps"][f"batched_{n}"]
            noop = r["ppo_fps"][f"noop_{n}"]
            tag = " (config)" if n == r["config_n_envs"] else ""
            batch = r["ppo_batch_size"][str(n)]
            span = ratio_range(r.get("ppo_fps_rounds"), f"batched_{n}", f"reference_{n}")
            lines.append(f"| {env_id} | {n}{tag} | {batch} | {_fmt(ref)} | {_fmt(bat)} | {bat / ref:.2f}x{span} | "
                         f"{_fmt(noop)} | {noop / ref:.2f}x |")
    lines += [
        "",
        "Reference VecEnvs: GridWorld `make_vec_env` (DummyVecEnv of Monitor-wrapped envs); TreasureHunt, "
        "simple spread and pursuit `sbagents.multiagent.parameter_sharing.ParameterSharingVecEnv` (the `policies: "
        "shared` team "
        "VecEnv). Medians of interleaved rounds (in brackets, where recorded: the range of the per-round ratios). "
        "*No-op* is "
        "`benchmarks.speed.noop_vec_env.NoOpVecEnv`: it returns fresh arrays and one fresh info dict per slot, as "
        "SB3 requires, and does no env work, so its figures are the ceiling of any VecEnv for these envs.",
    ]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run speed``."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks run speed",
                                     description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds per figure (median)")
    parser.add_argument("--quick", action="store_true", help="smoke run: a quarter of the steps, PPO one round")
    parser.add_argument("--envs", nargs="+", choices=ENV_IDS, default=list(ENV_IDS), help="env ids to measure")
    return parser


def run(argv: Sequence[str]) -> dict[str, Any]:
    """``python -m benchmarks run speed [OPTIONS]``: measure; the results record the command."""
    args = build_parser().parse_args(list(argv))
    results = measure(rounds=args.rounds, quick=args.quick, env_ids=tuple(args.envs))
    results["command"] = " ".join(["python -m benchmarks run speed", *recorded_argv(list(argv))])
    return results


BENCHMARKS = (
    Benchmark(name="speed", kind="speed", results="speed.json",
              summary="env steps/s and PPO fps: reference VecEnvs vs the batched numpy VecEnvs",
              run=run, render=markdown),
)
