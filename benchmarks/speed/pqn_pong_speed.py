"""What makes a PQN Pong step cheaper on this machine's CPU cores: each change measured alone, against the same
baseline, in one command.

The baseline is ``train --algo pqn --env PongNoFrameskip-v4`` with the shipped ``atari`` entry (CleanRL's
``pqn_atari_envpool`` settings: 128 envs x 32 steps per rollout, 2 epochs of minibatches of 128, the Nature CNN with
LayerNorm; EnvPool stepping the envs), 1 torch thread and OpenMP's default wait policy (idle threads spin). Each
other row changes one thing (two for the 2-thread rows: threads and the wait policy):

- ``OMP_WAIT_POLICY=PASSIVE`` (what ``train`` sets since this benchmark: :mod:`sbagents.openmp`), 1 and 2 threads,
  and 2 threads with spinning threads (what ``--num-threads 2`` did before);
- on top of 2 threads + PASSIVE: channels-last convolutions (``features_extractor_kwargs: {channels_last: true}``),
  ``torch.compile`` of the Q-network's forward (compile time excluded), and three changes of the algorithm's
  settings (not speed-only: they change what is learned per env step): 32 envs, minibatches of 512 (a quarter of
  the gradient steps), 1 epoch (half the gradient passes);
- the wait policy with few envs: 8 envs with 1 thread, 2 spinning threads and 2 PASSIVE threads (with few envs the
  gradient work is short and the env threads and torch's threads take turns on the cores, so spinning threads can
  take the cores from the env threads).

Each row trains in a fresh process (the wait policy is read when torch loads OpenMP) through ``train_sb3`` (the CLI's
code path, no evaluation): ``--warmup`` env steps, then at least ``--steps`` timed env steps, whole rollouts. Reported:
env steps/s, the ratio to the baseline, the share of the time spent in rollouts (acting and stepping; the rest is
the gradient work), gradient passes per env step (``n_epochs``: each transition goes forward and backward that many
times) and gradient steps per 1,000 env steps. Rows run in ``--rounds`` interleaved rounds (medians), so load on a
shared machine hits every row alike.

Also the env side alone, random actions at the baseline's 128 envs: EnvPool giving one frame per step with SB3's
``VecFrameStack`` on top (what training uses) against EnvPool's own 4-frame stack (``stack_num=4``)::

    python -m benchmarks run pqn-pong-speed [--steps 16384] [--rounds 1]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Sequence
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.report import load_average, machine_info, recorded_argv, run_module

NAME = "pqn-pong-speed"
ENV = "PongNoFrameskip-v4"
MODULE = "benchmarks.speed.pqn_pong_speed"

#: name -> (what changes, settings): threads, OpenMP wait policy (None: unset), zoo overrides, compile.
VARIANTS: dict[str, tuple[str, dict[str, Any]]] = {
    "baseline": ("CleanRL's settings, 1 thread, OpenMP default wait", {"threads": 1, "wait": None}),
    "passive-1": ("OMP_WAIT_POLICY=PASSIVE, 1 thread", {"threads": 1, "wait": "PASSIVE"}),
    "spin-2": ("2 threads, OpenMP default wait (spinning)", {"threads": 2, "wait": None}),
    "passive-2": ("2 threads, OMP_WAIT_POLICY=PASSIVE (train's default wait now)", {"threads": 2, "wait": "PASSIVE"}),
    "channels-last": ("passive-2 + channels-last convolutions",
                      {"threads": 2, "wait": "PASSIVE",
                       "params": {"policy_kwargs": {"features_extractor_kwargs": {"channels_last": True}}}}),
    "compile": ("passive-2 + torch.compile of the Q-network", {"threads": 2, "wait": "PASSIVE", "compile": True}),
    "envs-32": ("passive-2 + 32 envs (algorithm setting)", {"threads": 2, "wait": "PASSIVE",
                                                            "params": {"n_envs": 32}}),
    "batch-512": ("passive-2 + minibatches of 512 (algorithm setting)",
                  {"threads": 2, "wait": "PASSIVE", "params": {"batch_size": 512}}),
    "epochs-1": ("passive-2 + 1 epoch (algorithm setting)", {"threads": 2, "wait": "PASSIVE",
                                                             "params": {"n_epochs": 1}}),
    "envs-8": ("baseline with 8 envs (algorithm setting)", {"threads": 1, "wait": None, "params": {"n_envs": 8}}),
    "spin-2-envs-8": ("spin-2 with 8 envs (algorithm setting)", {"threads": 2, "wait": None,
                                                                 "params": {"n_envs": 8}}),
    "passive-2-envs-8": ("passive-2 with 8 envs (algorithm setting)", {"threads": 2, "wait": "PASSIVE",
                                                                       "params": {"n_envs": 8}}),
}
#: The zoo entry's settings the table reports per row (a row's params override them).
SHOWN = ("n_envs", "n_steps", "batch_size", "n_epochs")


def entry() -> dict[str, int]:
    """The shipped ``atari`` entry's :data:`SHOWN` settings for Pong (``zoo_configs/pqn.yml``)."""
    from sbagents.core.env_names import resolve_env
    from sbagents.core.experiment import build_experiment
    from sbagents.core.options import TrainSpec

    exp = build_experiment(TrainSpec("pqn", ENV), resolve_env(ENV))
    return {"n_envs": int(exp.n_envs), **{k: int(exp.algo_kwargs[k]) for k in SHOWN[1:]}}


def build_parser() -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run pqn-pong-speed``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME}", description=__doc__.splitlines()[0])
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS),
                        help="rows (default: all; the first is the ratios' baseline)")
    parser.add_argument("--steps", type=int, default=16_384, help="timed env steps per row (whole rollouts)")
    parser.add_argument("--warmup", type=int, default=8_192, help="env steps before the clock starts")
    parser.add_argument("--rounds", type=int, default=1, help="interleaved rounds (medians)")
    parser.add_argument("--env-steps", type=int, default=64, help="vector steps of the env-only comparison")
    parser.add_argument("--quick", action="store_true", help="smoke run: 2 rows, 8 envs, a few rollouts")
    return parser


def measure_one(settings: dict[str, Any], steps: int, warmup: int) -> dict[str, float]:
    """One row in this process: train for ``warmup`` + at least ``steps`` env steps; its rates."""
    from stable_baselines3.common.callbacks import BaseCallback

    from benchmarks.speed.atari_speed import StepClock
    from sbagents.core.options import EvalOptions, ExecOptions, OutputOptions, TrainSpec
    from sbagents.pipeline.training import train_sb3

    class Compile(BaseCallback):
        """``torch.compile`` of the Q-network's forward at the start of training."""

        def _on_training_start(self) -> None:
            import torch

            policy: Any = self.model.policy
            policy.q_values = torch.compile(policy.q_values)

        def _on_step(self) -> bool:
            return True

    params = {**settings.get("params", {})}
    shipped = entry()
    rollout = int(params.get("n_envs", shipped["n_envs"])) * int(params.get("n_steps", shipped["n_steps"]))
    warmup = -(-warmup // rollout) * rollout
    timed = -(-steps // rollout) * rollout
    clock = StepClock(warmup)
    callbacks: list[BaseCallback] = [Compile(), clock] if settings.get("compile") else [clock]
    with tempfile.TemporaryDirectory() as logs:
        result = train_sb3(TrainSpec("pqn", ENV, n_timesteps=warmup + timed, hyperparams=params),
                           OutputOptions(log_folder=logs), EvalOptions(eval_freq=0, final_eval_episodes=0),
                           ExecOptions(seed=0, num_threads=int(settings["threads"]), progress=False, verbose=0),
                           callbacks=callbacks)
        if result.model is not None and result.model.get_env() is not None:
            result.model.get_env().close()  # type: ignore[union-attr]
    seconds = clock.t1 - (clock.t0 or clock.t1)
    return {"fps": clock.fps, "rollout_share": clock.rollout_seconds / seconds if seconds > 0 else float("nan"),
            "timed_steps": clock.n1 - clock.n0}


def _row(name: str, steps: int, warmup: int, n_envs: int | None = None) -> dict[str, float]:
    """One row in a fresh process (its wait policy set or removed before torch loads OpenMP)."""
    settings = VARIANTS[name][1]
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "OMP_NUM_THREADS")}
    if settings["wait"] is not None:
        env["OMP_WAIT_POLICY"] = settings["wait"]
    extra = ["--n-envs", str(n_envs)] if n_envs is not None else []
    out = run_module(MODULE, "--one", name, "--steps", str(steps), "--warmup", str(warmup), *extra, env=env)
    return json.loads(out.strip().splitlines()[-1])  # type: ignore[no-any-return]


def _fps(step: Any, n_envs: int, vector_steps: int, seed: int) -> float:
    """Env steps/s of ``step(actions)`` with random actions of Pong's 6."""
    import numpy as np

    actions = np.random.default_rng(seed).integers(6, size=(vector_steps, n_envs))
    start = time.perf_counter()
    for a in actions:
        step(a)
    return vector_steps * n_envs / (time.perf_counter() - start)


def env_only(n_envs: int, vector_steps: int, seed: int = 0) -> dict[str, float]:
    """Env steps/s with random actions of training's envs (sbagents' EnvPool VecEnv, one frame per step, with SB3's
    ``VecFrameStack``), of that VecEnv without the stack, and of EnvPool's own pool with ``stack_num`` 1 and 4."""
    from sbagents.atari.envpool_support import atari_settings
    from sbagents.atari.envpool_vec_env import default_threads, envpool_task_id, import_envpool
    from sbagents.core.env_names import resolve_env
    from sbagents.core.experiment import build_experiment
    from sbagents.core.options import TrainSpec
    from sbagents.env_factory import make_vec

    ref = resolve_env(ENV)
    exp = build_experiment(TrainSpec("pqn", ENV), ref)
    rates = {}
    venv = make_vec(exp, ref, n_envs, seed, vec_env="envpool")
    for key, env in (("training_fps", venv), ("no_stack_fps", venv.venv)):  # type: ignore[attr-defined]
        env.reset()
        rates[key] = _fps(env.step, n_envs, vector_steps, seed)
    venv.close()
    envpool, settings = import_envpool(), atari_settings(exp, ref)
    for stack in (1, 4):
        pool = envpool.make(envpool_task_id(settings.game), env_type="gymnasium", num_envs=n_envs, seed=seed,
                            num_threads=default_threads(n_envs),
                            **{**settings.envpool_kwargs(), "stack_num": stack})
        pool.reset()
        rates[f"envpool_stack{stack}_fps"] = _fps(pool.step, n_envs, vector_steps, seed)
        pool.close()
    return rates


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Every row's medians over the rounds, and the env-only comparison."""
    args = build_parser().parse_args(list(argv))
    if args.quick:
        args.variants, args.steps, args.warmup, args.rounds, args.env_steps = args.variants[:2], 256, 256, 1, 8
    load_before = load_average()
    n_envs = 8 if args.quick else None  # None: each row's own
    samples: dict[str, list[dict[str, float]]] = {name: [] for name in args.variants}
    for _ in range(args.rounds):
        for name in args.variants:
            samples[name].append(_row(name, args.steps, args.warmup, n_envs))
    rows, shipped = [], entry()
    for name in args.variants:
        what, settings = VARIANTS[name]
        row = {**shipped, **{k: v for k, v in settings.get("params", {}).items() if k in SHOWN}}
        row["n_envs"] = n_envs or row["n_envs"]
        rows.append({"variant": name, "what": what, **row,
                     "fps": round(statistics.median(s["fps"] for s in samples[name]), 1),
                     "fps_rounds": [round(s["fps"], 1) for s in samples[name]],
                     "rollout_share": round(statistics.median(s["rollout_share"] for s in samples[name]), 3),
                     "gradient_passes_per_step": row["n_epochs"],
                     "gradient_steps_per_1000": round(1000 * row["n_epochs"] / row["batch_size"], 2)})
    env_envs = n_envs or shipped["n_envs"]
    return {"command": " ".join(["python -m benchmarks run", NAME, *recorded_argv(list(argv))]), "env": ENV,
            "rows": rows, "env_only": {"n_envs": env_envs, **env_only(env_envs, args.env_steps)},
            "machine": {**machine_info(), "load_before": load_before, "load_after": load_average()}}


def render(results: dict[str, Any]) -> str:
    """The section: one row per change, the env-only comparison."""
    m = results["machine"]
    base = results["rows"][0]["fps"]
    lines = [f"## PQN on Pong: what makes a step cheaper on {m['cores']} CPU cores", "",
             f"Command: `{results['command']}`. Each row trains `--algo pqn` on {results['env']} in a fresh process "
             "(EnvPool stepping the envs, the `atari` entry otherwise), timed after a warm-up; the first row is the "
             "baseline of the ratios. Rows whose change says *algorithm setting* change what is learned per env step "
             "(how many gradient steps, on how many envs' data); the others only its speed. "
             f"{m['cpu']}, {m['date']}, load {m['load_before'][0]} before / {m['load_after'][0]} after.",
             "",
             "| row | what changes | envs | minibatch | gradient passes per env step | gradient steps per 1k env steps "
             "| env steps/s | vs baseline | share in rollouts |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in results["rows"]:
        lines.append(f"| {r['variant']} | {r['what']} | {r['n_envs']} | {r['batch_size']} | "
                     f"{r['gradient_passes_per_step']} | {r['gradient_steps_per_1000']:g} | {r['fps']:,.0f} | "
                     f"{r['fps'] / base:.2f}x | {r['rollout_share']:.0%} |")
    e = results["env_only"]
    ms = {k: 1000 / v for k, v in e.items() if k.endswith("_fps")}
    lines += ["", f"The env side alone ({e['n_envs']} envs, random actions), ms per env step: training's envs "
              f"(sbagents' EnvPool VecEnv + SB3's `VecFrameStack`) {ms['training_fps']:.3f}, without the stack "
              f"{ms['no_stack_fps']:.3f}; EnvPool's pool alone with 1 frame {ms['envpool_stack1_fps']:.3f}, with its "
              f"own 4-frame stack {ms['envpool_stack4_fps']:.3f}. A baseline training step takes {1000 / base:.3f} "
              "ms, so moving the stack into EnvPool could save at most "
              f"{(ms['training_fps'] - ms['no_stack_fps']) / (1000 / base):.1%} of it."]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> None:
    """``python -m benchmarks.speed.pqn_pong_speed --one ROW``: one row's rates as a JSON line (the subprocess)."""
    parser = argparse.ArgumentParser()
    parser.add_argument("--one", required=True, choices=list(VARIANTS))
    parser.add_argument("--steps", type=int, required=True)
    parser.add_argument("--warmup", type=int, required=True)
    parser.add_argument("--n-envs", type=int, default=None)
    args = parser.parse_args(argv)
    settings = VARIANTS[args.one][1]
    if args.n_envs is not None:
        settings = {**settings, "params": {**settings.get("params", {}), "n_envs": args.n_envs}}
    print(json.dumps(measure_one(settings, args.steps, args.warmup)))


BENCHMARKS = (
    Benchmark(name=NAME, kind="speed", results="pqn_pong_speed.json",
              summary="PQN on Pong: env steps/s of each change (threads, OpenMP wait, channels-last, compile, ...)",
              run=run, render=render),
)

if __name__ == "__main__":
    main(sys.argv[1:])
