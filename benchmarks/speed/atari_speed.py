"""Atari throughput side by side on Pong: DummyVecEnv, SubprocVecEnv and EnvPool, in one command.

For each vec env kind (``--vec-env dummy``, ``subproc``, ``envpool``):

- env-only steps/s: the Pong PPO entry's env (``AtariWrapper`` + 4-frame stack on the ALE env, or EnvPool + the
  same ``VecFrameStack``) at ``--n-envs`` copies, random actions, resets included;
- PPO training fps through the CLI's code path (``train_sb3`` with the ``PongNoFrameskip-v4`` entry at
  ``--n-envs``, ``batch_size`` scaled to keep its 8 minibatches), timed after one warm-up rollout;
- DQN training fps (the ``atari`` entry: one env, a gradient step every 4 steps), timed after ``learning_starts``.

Rounds are interleaved (dummy, subproc, envpool, dummy, ...) so load on a shared machine hits every kind alike;
the medians and the ratios against DummyVecEnv (the default vec env before EnvPool) are reported, with the load
average. Sized for the project's 2-core machines by default; on a many-core GPU machine, where the env side is the
bottleneck::

    python -m benchmarks run atari-speed                                 # 2 cores: 8 envs, ~10-12 min
    python -m benchmarks run atari-speed --n-envs 16 --device cuda --rounds 1 --ppo-rollouts 4 --dqn-steps 4000
    python -m benchmarks run --output '' --results SCRATCH.json atari-speed --quick   # smoke run

Results: ``benchmarks/results/atari_speed.json``; section ``atari-speed`` of ``BENCHMARKS.md``.

Needs EnvPool (``pip install -e ".[atari]"``); without it the envpool column is left out.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback

from benchmarks.harness import Benchmark
from benchmarks.report import cpu_model, recorded_argv

ENV_ID = "PongNoFrameskip-v4"
KINDS: tuple[str, ...] = ("dummy", "subproc", "envpool")
SECTION = "atari-speed"


class StepClock(BaseCallback):
    """Wall and process CPU time from the first step at or after ``start_step`` to the end of training, and the
    wall time and steps of the rollouts collected after ``start_step`` (on-policy algorithms: the part of training
    where the env is stepped, without the gradient updates)."""

    def __init__(self, start_step: int) -> None:
        super().__init__()
        self.start_step = start_step
        self.t0: float | None = None
        self.n0 = self.n1 = 0
        self.t1 = self.c0 = self.c1 = 0.0
        self.rollout_seconds = 0.0
        self.rollout_steps = 0
        self._rollout_start: tuple[float, int] | None = None

    def _on_rollout_start(self) -> None:
        self._rollout_start = (time.perf_counter(), self.num_timesteps) if self.t0 is not None else None

    def _on_rollout_end(self) -> None:
        if self._rollout_start is not None:
            self.rollout_seconds += time.perf_counter() - self._rollout_start[0]
            self.rollout_steps += self.num_timesteps - self._rollout_start[1]

    @property
    def rollout_fps(self) -> float:
        """Steps per second of the timed rollouts (nan without any)."""
        return self.rollout_steps / self.rollout_seconds if self.rollout_seconds > 0 else float("nan")

    def _on_step(self) -> bool:
        if self.t0 is None and self.num_timesteps >= self.start_step:
            self.t0, self.n0, self.c0 = time.perf_counter(), self.num_timesteps, time.process_time()
        return True

    def _on_training_end(self) -> None:
        self.t1, self.n1, self.c1 = time.perf_counter(), self.num_timesteps, time.process_time()

    @property
    def cpu_fps(self) -> float:
        """Steps per second of this process's CPU time (all its threads) over the same span."""
        if self.t0 is None or self.n1 <= self.n0:
            return float("nan")
        return (self.n1 - self.n0) / max(self.c1 - self.c0, 1e-9)

    @property
    def fps(self) -> float:
        """Steps per second between ``start_step`` and the end (nan if never reached)."""
        if self.t0 is None or self.n1 <= self.n0:
            return float("nan")
        return (self.n1 - self.n0) / max(self.t1 - self.t0, 1e-9)


def ppo_params(n_envs: int, n_steps: int = 128, minibatches: int = 8) -> dict[str, Any]:
    """Overrides of the Pong PPO entry for ``n_envs`` envs: the same rollout length and number of minibatches."""
    return {"n_envs": n_envs, "n_steps": n_steps, "batch_size": max(n_envs * n_steps // minibatches, 32)}


def env_rate(kind: str, n_envs: int, n_steps: int, seed: int = 0) -> float:
    """Env transitions/s of ``n_envs`` copies of the Pong entry's env on ``kind``, random actions, resets included
    (``n_steps`` transitions, after a few untimed steps; worker start-up excluded)."""
    return env_rates(kind, n_envs, n_steps, seed)[0]


def env_rates(kind: str, n_envs: int, n_steps: int, seed: int = 0) -> tuple[float, float]:
    """:func:`env_rate` and the same transitions per second of this process's CPU time (all its threads, EnvPool's
    included; not SubprocVecEnv's worker processes): what one free core would give, whatever the load."""
    from sbagents.core.env_names import resolve_env
    from sbagents.core.experiment import build_experiment
    from sbagents.core.options import TrainSpec
    from sbagents.env_factory import make_vec

    ref = resolve_env(ENV_ID)
    exp = build_experiment(TrainSpec("ppo", ENV_ID), ref)
    venv = make_vec(exp, ref, n_envs, seed, vec_env=kind)
    rng = np.random.default_rng(seed)
    n_actions = int(venv.action_space.n)  # type: ignore[attr-defined]
    venv.reset()
    for _ in range(5):
        venv.step(rng.integers(n_actions, size=n_envs))
    vector_steps = max(n_steps // n_envs, 1)
    actions = rng.integers(n_actions, size=(vector_steps, n_envs))
    start, cpu_start = time.perf_counter(), time.process_time()
    for a in actions:
        venv.step(a)
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
    venv.close()
    return vector_steps * n_envs / seconds, vector_steps * n_envs / max(cpu_seconds, 1e-9)


def train_clock(algo: str, kind: str, params: dict[str, Any], warmup: int, timed: int, device: str = "cpu",
                seed: int = 0) -> StepClock:
    """Train ``algo`` on Pong through ``train_sb3`` (the CLI's code path, no evaluations) for ``warmup + timed``
    steps, the run dir in a temporary folder; the returned clock timed the steps after ``warmup``."""
    from sbagents.core.options import EvalOptions, ExecOptions, OutputOptions, Sb3Options, TrainSpec
    from sbagents.pipeline.training import train_sb3

    clock = StepClock(warmup)
    with tempfile.TemporaryDirectory() as logs:
        result = train_sb3(TrainSpec(algo, ENV_ID, n_timesteps=warmup + timed, hyperparams=dict(params)),
                           OutputOptions(log_folder=logs), EvalOptions(eval_freq=0, final_eval_episodes=0),
                           ExecOptions(seed=seed, device=device, num_threads=1, progress=False, verbose=0),
                           callbacks=[clock], sb3=Sb3Options(vec_env=kind))
        env = result.model.get_env() if result.model is not None else None
        if env is not None:
            env.close()  # SubprocVecEnv's workers end now, not when the pipes are collected
    return clock


def train_fps(algo: str, kind: str, params: dict[str, Any], warmup: int, timed: int, device: str = "cpu",
              seed: int = 0) -> float:
    """Training steps/s of :func:`train_clock`."""
    return train_clock(algo, kind, params, warmup, timed, device, seed).fps


def dqn_params(learning_starts: int) -> dict[str, Any]:
    """Overrides of the DQN ``atari`` entry for a short timing: a small buffer, learning from ``learning_starts``."""
    return {"buffer_size": 20_000, "learning_starts": learning_starts}


def measure(kinds: Sequence[str], n_envs: int, rounds: int, env_steps: int, ppo_rollouts: int, dqn_steps: int,
            device: str = "cpu", on_result: Callable[[str, str, float], None] | None = None,
            env_rounds: int | None = None) -> dict[str, Any]:
    """Every figure for every kind in ``rounds`` interleaved rounds (``env_rounds`` for the cheap env-only
    figures; default ``rounds``): ``{"env": {kind: [..]}, "env_cpu": ..., "ppo": ..., "dqn": ...}`` (steps/s per
    round). ``on_result(what, kind, value)`` sees each figure as it is measured."""
    rollout = n_envs * 128
    learning_starts = 1000
    samples: dict[str, dict[str, list[float]]] = {
        what: {k: [] for k in kinds}
        for what in ("env", "env_cpu", "ppo_rollout", "ppo", "ppo_cpu", "dqn", "dqn_cpu")}

    def keep_cpu(what: str, kind: str, cpu: float) -> None:
        if kind != "subproc":  # its workers' CPU time is not this process's
            samples[f"{what}_cpu"][kind].append(cpu)

    def env_job(kind: str) -> float:
        wall, cpu = env_rates(kind, n_envs, env_steps)
        keep_cpu("env", kind, cpu)
        return wall

    def train_job(what: str, kind: str) -> float:
        clock = (train_clock("ppo", kind, ppo_params(n_envs), rollout, ppo_rollouts * rollout, device)
                 if what == "ppo" else
                 train_clock("dqn", kind, dqn_params(learning_starts), learning_starts, dqn_steps, device))
        keep_cpu(what, kind, clock.cpu_fps)
        if what == "ppo":
            samples["ppo_rollout"][kind].append(clock.rollout_fps)
        return clock.fps

    jobs: dict[str, Callable[[str], float]] = {
        "env": env_job,
        "ppo": lambda kind: train_job("ppo", kind),
        "dqn": lambda kind: train_job("dqn", kind),
    }
    env_rounds = rounds if env_rounds is None else env_rounds
    for r in range(max(rounds, env_rounds)):
        for what, job in jobs.items():
            if (what == "ppo" and (ppo_rollouts <= 0 or r >= rounds)) or (what == "dqn" and (dqn_steps <= 0 or
                                                                                            r >= rounds)):
                continue
            if what == "env" and r >= env_rounds:
                continue
            for kind in (kinds if r % 2 == 0 else kinds[::-1]):  # alternate the order: a load trend hits all
                value = job(kind)
                samples[what][kind].append(value)
                if on_result is not None:
                    on_result(what, kind, value)
    return samples


def summarize(samples: dict[str, dict[str, list[float]]]) -> dict[str, dict[str, Any]]:
    """Median per kind and the median of the per-round ratios against ``dummy`` (when measured)."""
    out: dict[str, dict[str, Any]] = {}
    for what, by_kind in samples.items():
        if not any(by_kind.values()):
            continue
        row: dict[str, Any] = {k: statistics.median(v) for k, v in by_kind.items() if v}
        base = by_kind.get("dummy") or []
        for kind, values in by_kind.items():
            if kind != "dummy" and base and values:
                row[f"{kind}/dummy"] = statistics.median(v / b for v, b in zip(values, base, strict=False))
        out[what] = row
    return out


def markdown(results: dict[str, Any]) -> str:
    """The ``atari-speed`` section of BENCHMARKS.md, from the results alone (``notes``: a closing paragraph)."""
    m, table = results["machine"], results["summary"]
    kinds = [k for k in KINDS if k in results["kinds"]]
    lines = [
        "## Atari at engine speed: Pong with DummyVecEnv, SubprocVecEnv and EnvPool",
        "",
        f"Command: `{results['command']}` "
        f"({m['cpu']}, {m['cores']} cores, {m['device']}, torch {m['torch']} 1 thread, envpool {m['envpool']}; "
        f"{m['date']}; load average {m['load_before']} before, {m['load_after']} after; "
        f"{results.get('env_rounds', results['rounds'])} interleaved env-only rounds and {results['rounds']} "
        f"training round(s), medians; {results['seconds']:.0f} s).",
        f"{results['n_envs']} envs; env-only: random actions, resets included, the same preprocessing "
        "(AtariWrapper + 4-frame stack; EnvPool + the same VecFrameStack); PPO: the `PongNoFrameskip-v4` entry "
        f"(n_steps 128, batch {ppo_params(results['n_envs'])['batch_size']}), timed after one rollout; DQN: the "
        "`atari` entry (1 env), timed after `learning_starts`. Ratios: median of the per-round ratios to DummyVecEnv "
        "(the default vec env before EnvPool); rounds alternate the order of the kinds. PPO rollout collection: "
        "the steps/s of the timed rollouts alone (SB3's loop without the gradient updates). Per CPU-second: the "
        "same steps over the process's CPU time "
        "(EnvPool's threads included; SubprocVecEnv's workers are other processes, so none for it), i.e. what one "
        "free core gives whatever the load; EnvPool also spreads its envs over every free core, which only the "
        "wall figures of a quiet machine show.",
        "",
        "| steps/s | " + " | ".join(kinds) + " | " + " | ".join(f"{k} / dummy" for k in kinds if k != "dummy") + " |",
        "|---|" + "---:|" * (2 * len(kinds) - 1),
    ]
    names = {"env": "env only", "env_cpu": "env only, per CPU-second",
             "ppo_rollout": "PPO rollout collection (policy forward + env step)", "ppo": "PPO training",
             "ppo_cpu": "PPO training, per CPU-second", "dqn": "DQN training",
             "dqn_cpu": "DQN training, per CPU-second"}
    for what, row in table.items():
        cells = [f"{row[k]:,.0f}" if k in row else "-" for k in kinds]
        ratios = [f"{row[f'{k}/dummy']:.2f}x" if f"{k}/dummy" in row else "-" for k in kinds if k != "dummy"]
        lines.append(f"| {names[what]} | " + " | ".join(cells + ratios) + " |")
    lines += ["", targets_paragraph(results)]
    if results.get("notes"):
        lines += ["", results["notes"]]
    return "\n".join(lines)


def round_ratios(samples: dict[str, dict[str, list[float]]], kind: str = "envpool") -> dict[str, list[float]]:
    """Per measure, the per-round ratios of ``kind`` to ``dummy`` (rounds where both were measured)."""
    return {what: [v / b for v, b in zip(by_kind[kind], by_kind["dummy"], strict=False)]
            for what, by_kind in samples.items() if by_kind.get(kind) and by_kind.get("dummy")}


def targets_paragraph(results: dict[str, Any]) -> str:
    """The per-round EnvPool / DummyVecEnv ranges and the two targets on this machine (env only >= 2x, PPO
    training > 1x), from the results alone."""
    ratios = round_ratios(results["samples"])
    if "env" not in ratios:
        return "EnvPool was not measured (not installed): no ratios."
    names = {"env": "env only", "ppo_rollout": "PPO rollout collection", "ppo": "PPO training", "dqn": "DQN"}
    spans = [f"{names[w]} {min(r):.2f}-{max(r):.2f}x" for w, r in ratios.items() if w in names and r]
    summary = results["summary"]
    env = summary["env"]["envpool/dummy"]
    text = (f"Per-round envpool / dummy ratios: {'; '.join(spans)}. Targets on {results['machine']['cores']} cores "
            f"({results['n_envs']} envs): env-only stepping at least 2x DummyVecEnv + AtariWrapper: "
            f"{'met' if env >= 2.0 else 'not met'} ({env:.2f}x)")
    if "ppo" in summary and "envpool/dummy" in summary["ppo"]:
        ppo = summary["ppo"]["envpool/dummy"]
        text += f"; PPO training faster than with DummyVecEnv: {'met' if ppo > 1.0 else 'not met'} ({ppo:.2f}x)"
    return text + "."


def machine(device: str) -> dict[str, Any]:
    """CPU, cores, device, versions and date."""
    try:
        from importlib.metadata import version

        envpool_version = version("envpool")
    except Exception:  # noqa: BLE001 - not installed
        envpool_version = "not installed"
    dev = device
    if device.startswith("cuda") and torch.cuda.is_available():
        dev = f"{device} ({torch.cuda.get_device_name(0)})"
    return {"cpu": cpu_model(), "cores": os.cpu_count(), "device": dev, "torch": torch.__version__,
            "python": platform.python_version(), "envpool": envpool_version, "date": time.strftime("%Y-%m-%d %H:%M")}


def build_parser() -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run atari-speed``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n-envs", type=int, default=8, help="env copies (PPO and env-only)")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved training rounds (medians reported)")
    parser.add_argument("--env-rounds", type=int, default=9, help="interleaved env-only rounds (a few s each)")
    parser.add_argument("--env-steps", type=int, default=8000, help="timed env transitions per env-only figure")
    parser.add_argument("--ppo-rollouts", type=int, default=2, help="timed PPO rollouts (0: no PPO figure)")
    parser.add_argument("--dqn-steps", type=int, default=1000, help="timed DQN steps (0: no DQN figure)")
    parser.add_argument("--device", default="cpu", help="torch device of the models")
    parser.add_argument("--kinds", nargs="+", choices=KINDS, default=list(KINDS), help="vec env kinds")
    parser.add_argument("--quick", action="store_true", help="1 round, 2000 env steps, 1 PPO rollout, 300 DQN steps")
    return parser


def run(argv: Sequence[str]) -> dict[str, Any]:
    """``python -m benchmarks run atari-speed [OPTIONS]``: measure; the results record the command."""
    parser = build_parser()
    args = parser.parse_args(list(argv))
    if args.quick:
        args.rounds, args.env_rounds, args.env_steps, args.ppo_rollouts, args.dqn_steps = 1, 1, 2000, 1, 300
    if min(args.n_envs, args.rounds, args.env_steps) < 1:
        parser.error("--n-envs, --rounds and --env-steps must be >= 1")
    from sbagents.atari import envpool_installed

    kinds = [k for k in args.kinds if k != "envpool" or envpool_installed()]
    if len(kinds) < len(args.kinds):
        print('EnvPool is not installed (pip install -e ".[atari]"): its column is left out', file=sys.stderr)
    torch.set_num_threads(1)
    load_before = round(os.getloadavg()[0], 2)
    started = time.perf_counter()
    samples = measure(kinds, args.n_envs, args.rounds, args.env_steps, args.ppo_rollouts, args.dqn_steps,
                      args.device, on_result=lambda w, k, v: print(f"{w:>4} {k:>8}: {v:,.0f} steps/s", flush=True),
                      env_rounds=args.env_rounds)
    info = machine(args.device)
    info.update(load_before=load_before, load_after=round(os.getloadavg()[0], 2))
    return {"command": " ".join(["python -m benchmarks run", SECTION, *recorded_argv(list(argv))]),
            "machine": info, "kinds": kinds, "n_envs": args.n_envs, "rounds": args.rounds,
            "env_rounds": args.env_rounds,
            "seconds": time.perf_counter() - started, "samples": samples, "summary": summarize(samples)}


BENCHMARKS = (
    Benchmark(name=SECTION, kind="speed", results="atari_speed.json",
              summary="Pong env and PPO/DQN training steps/s: DummyVecEnv vs SubprocVecEnv vs EnvPool",
              run=run, render=markdown),
)
