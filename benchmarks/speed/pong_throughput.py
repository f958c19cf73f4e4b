"""DQN on PongNoFrameskip-v4 through the sbagents CLI's code path: throughput and replay-buffer memory.

Measures on this machine (1 torch thread):

- ``env_fps``: agent steps/s of the wrapped env alone (AtariWrapper + 4-frame stack, random actions);
- ``train_fps``: agent steps/s of ``sbagents.pipeline.training.train`` with the ``atari`` zoo entry *after*
  ``learning_starts`` (one gradient step of batch 32 every 4 steps, as in the 10M-step recipe);
- the hours 10M steps (the budget of the published +20.6) would take at ``train_fps``;
- the bytes of the default replay buffer (1e5 transitions, ``optimize_memory_usage``) and the process's
  peak RSS during the short run.

and, from the run dir of a long run (``--report RUN_DIR``, 1 seed), its learning curve (``pong_dqn_curve.png``),
evaluations and speed. Usage::

    python -m benchmarks run pong --warmup-steps 1000 --train-steps 4000      # the short benchmark
    python -m benchmarks run pong --report RUN_DIR --rss-log RSS_LOG          # + the long run's curve and table

Results: ``benchmarks/results/pong.json`` (``throughput``: the short benchmark, ``long_run``: the long run); the
part a command does not measure is kept from the results file there. Section ``pong`` of ``BENCHMARKS.md``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import resource
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecTransposeImage

from benchmarks.harness import Benchmark
from benchmarks.report import RESULTS_DIR, load_results, recorded_argv
from sbagents.api import EvalOptions, ExecOptions, OutputOptions, TrainSpec, train
from sbagents.core.env_names import resolve_env
from sbagents.core.experiment import build_experiment
from sbagents.env_factory import make_vec

ENV_ID = "PongNoFrameskip-v4"
PUBLISHED_BUDGET = 10_000_000
SECTION = "pong"
RESULTS_NAME, PNG_NAME = "pong.json", "pong_dqn_curve.png"


class StepClock(BaseCallback):
    """Records wall time at the first step at or after ``start_step`` and at the end of training."""

    def __init__(self, start_step: int) -> None:
        super().__init__()
        self.start_step = start_step
        self.t0: float | None = None
        self.n0 = 0
        self.t1 = 0.0
        self.n1 = 0
        self.cpu0 = 0.0
        self.cpu1 = 0.0

    def _on_step(self) -> bool:
        if self.t0 is None and self.num_timesteps >= self.start_step:
            self.t0, self.n0, self.cpu0 = time.perf_counter(), self.num_timesteps, time.process_time()
        return True

    def _on_training_end(self) -> None:
        self.t1, self.n1, self.cpu1 = time.perf_counter(), self.num_timesteps, time.process_time()

    @property
    def fps(self) -> float:
        """Steps per second between ``start_step`` and the end."""
        if self.t0 is None:
            return float("nan")
        return (self.n1 - self.n0) / max(self.t1 - self.t0, 1e-9)

    @property
    def fps_per_cpu_second(self) -> float:
        """Steps per second of this process's CPU time (what one unloaded core would give)."""
        if self.t0 is None:
            return float("nan")
        return (self.n1 - self.n0) / max(self.cpu1 - self.cpu0, 1e-9)


def env_fps(n_steps: int, seed: int = 0) -> float:
    """Agent steps/s of the wrapped Pong env with random actions."""
    ref = resolve_env(ENV_ID)
    exp = build_experiment(TrainSpec("dqn", ENV_ID), ref)
    venv = make_vec(exp, ref, 1, seed)
    venv.reset()
    rng = np.random.default_rng(seed)
    start = time.perf_counter()
    for _ in range(n_steps):
        venv.step(rng.integers(venv.action_space.n, size=1))  # type: ignore[attr-defined]
    seconds = time.perf_counter() - start
    venv.close()
    return n_steps / seconds


def default_buffer_bytes() -> dict[str, Any]:
    """Bytes of the default ``atari`` replay buffer (allocated lazily by numpy, so this is instant)."""
    ref = resolve_env(ENV_ID)
    exp = build_experiment(TrainSpec("dqn", ENV_ID), ref)
    venv = VecTransposeImage(make_vec(exp, ref, 1, 0))  # SB3 stores images channel-first
    kwargs = exp.algo_kwargs
    buffer = ReplayBuffer(
        int(kwargs["buffer_size"]),
        venv.observation_space,
        venv.action_space,
        device="cpu",
        optimize_memory_usage=bool(kwargs["optimize_memory_usage"]),
        **kwargs["replay_buffer_kwargs"],
    )
    venv.close()
    arrays = [buffer.observations, buffer.actions, buffer.rewards, buffer.dones, buffer.timeouts]
    if not buffer.optimize_memory_usage:
        arrays.append(buffer.next_observations)
    total = int(sum(a.nbytes for a in arrays))
    return {
        "buffer_size": int(kwargs["buffer_size"]),
        "obs_shape": list(venv.observation_space.shape or ()),
        "optimize_memory_usage": buffer.optimize_memory_usage,
        "buffer_bytes": total,
        "buffer_gib": round(total / 2**30, 3),
        "without_optimize_gib": round((total + buffer.observations.nbytes) / 2**30, 3),
    }


def _monitor_rows(run_dir: Path) -> np.ndarray:
    """``(t, r, l)`` of every monitor row, ordered by end time (t in seconds since the run started)."""
    rows, starts = [], []
    for path in run_dir.glob("*monitor.csv"):
        with path.open() as fh:
            starts.append(float(json.loads(fh.readline()[1:])["t_start"]))
            rows += [
                (starts[-1] + float(r["t"]), float(r["r"]), float(r["l"]))
                for r in csv.DictReader(fh)
                if r["l"]
            ]
    data = np.asarray(sorted(rows), dtype=np.float64).reshape(-1, 3)
    data[:, 0] -= min(starts, default=0.0)
    return data


def long_run(run_dir: Path, png_path: Path, rss_log: Path | None) -> dict[str, Any]:
    """The learning curve PNG (``png_path``) and the figures of a (possibly still running) Pong run: speed, training
    return, peak RSS (from ``rss_log``: ``<unix time> <rss KiB>`` lines) and one row per evaluation."""
    from sbagents.core.run_dir import RunRef
    from sbagents.visualize.curves import load_run_curve, plot

    curve = load_run_curve(run_dir, ENV_ID)
    mon = _monitor_rows(run_dir)
    steps = curve.timesteps
    seconds = mon[:, 0]
    plot(
        RunRef("dqn", ENV_ID, run_dir.parent.parent),
        output=png_path,
        title=f"DQN {ENV_ID}, default atari config, {int(steps[-1]):,} steps (nice 19, loaded 2-core CPU)",
    )
    evals = []
    with np.load(run_dir / "evaluations.npz") as data:
        ev_steps, results = data["timesteps"], data["results"]
    for step, res in zip(ev_steps, results, strict=True):
        done = curve.returns[steps <= step][-10:]
        evals.append({"timestep": int(step), "minutes": float(np.interp(step, steps, seconds)) / 60,
                      "eval_mean": float(res.mean()), "eval_std": float(res.std()), "eval_games": int(res.size),
                      "train_last10": float(done.mean()) if len(done) else None})
    after = steps > 100_000
    fps_learning = None
    if after.sum() > 1:
        fps_learning = float((steps[after][-1] - steps[after][0]) / max(seconds[after][-1] - seconds[after][0], 1e-9))
    peak = None
    if rss_log is not None and rss_log.exists():
        peak = float(np.loadtxt(rss_log, ndmin=2)[:, 1].max() / 2**20)
    command = (run_dir / "command.txt").read_text().strip() if (run_dir / "command.txt").exists() else "?"
    return {"seeds": 1, "command": command, "steps": int(steps[-1]), "games": len(curve.returns),
            "minutes": float(seconds[-1]) / 60,
            "fps_overall": float((steps[-1] - steps[0]) / max(seconds[-1] - seconds[0], 1e-9)),
            "fps_learning": fps_learning, "train_return_last10": float(curve.returns[-10:].mean()),
            "peak_rss_gib": peak, "evals": evals}


def _fmt(x: float | None, fmt: str) -> str:
    return "-" if x is None else f"{x:{fmt}}"


def markdown(results: dict[str, Any]) -> str:
    """The ``pong`` section, from the results alone."""
    run, tp = results["long_run"], results["throughput"]
    lines = [
        f"## Pong: DQN on {ENV_ID}: throughput and a (short) learning curve",
        "",
        f"Written by `{results['command']}` from the run's",
        "monitor files and `evaluations.npz` (1 seed, so no interval); curve: `pong_dqn_curve.png`; short benchmark:",
        f"`{tp['command']}`.",
        f"Run: `nice -n 19 nohup {run['command']}` (RL Zoo's `atari` entry: AtariWrapper, 4-frame stack, CnnPolicy,",
        "1e5 buffer with optimize_memory_usage, learning_starts 1e5, exploration over the first 1e6 steps).",
        "Published with this recipe: +20.6 +- 0.6 after 1e7 steps. Timings on a shared, loaded 2-core CPU",
        "(3-4 other engineers' jobs; the long run was niced to 19, so it got what the others left).",
        "",
        f"- reached {run['steps']:,} steps ({run['games']} games) in {run['minutes']:.0f} min;",
        f"  {run['fps_overall']:.0f} steps/s overall, {_fmt(run['fps_learning'], '.0f')} steps/s once learning "
        "started (after 100k steps)",
        f"- training return over the last 10 games: {run['train_return_last10']:.1f}",
    ]
    if run.get("peak_rss_gib") is not None:
        lines.append(f"- peak RSS of the training process: {run['peak_rss_gib']:.2f} GiB "
                     "(sampled every 30 s; the replay buffer is full from step 100,000 on)")
    lines += [
        f"- benchmark (not niced, {tp['train_steps_measured']} learning steps): {tp['train_fps']} "
        f"steps/s wall, {tp['train_fps_per_cpu_second']} per CPU-second; 10M steps: "
        f"{tp['hours_for_10M_steps']} h at that wall rate, {tp['hours_for_10M_steps_one_free_core']} h "
        f"on one free core; env alone {tp['env_fps']} steps/s; load average "
        f"{tp['load_avg_before'][0]:.1f} on {tp['cpu_count']} cores",
        "",
        "| timesteps | wall time (min) | eval return (mean +- std, 5 games) | training return (last 10 games) |",
        "|---:|---:|---:|---:|",
    ]
    for ev in run["evals"]:
        lines.append(f"| {ev['timestep']:,} | {ev['minutes']:.0f} | {ev['eval_mean']:.1f} +- {ev['eval_std']:.1f} | "
                     f"{_fmt(ev['train_last10'], '.1f')} |")
    lines += ["", f"![Pong DQN curve](benchmarks/results/{PNG_NAME})"]
    return "\n".join(lines)


def throughput(warmup_steps: int, train_steps: int, n_env_steps: int) -> dict[str, Any]:
    """The short benchmark: env-only steps/s, DQN steps/s after ``learning_starts``, buffer bytes, peak RSS."""
    torch.set_num_threads(1)
    result: dict[str, Any] = {"env": ENV_ID, "load_avg_before": list(os.getloadavg())}
    result["env_fps"] = round(env_fps(n_env_steps), 1)
    clock = StepClock(warmup_steps)
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        spec = TrainSpec("dqn", ENV_ID, warmup_steps + train_steps,
                         {"buffer_size": 10_000, "learning_starts": warmup_steps})
        run = train(spec, OutputOptions(tmp), EvalOptions(eval_freq=-1, final_eval_episodes=0),
                    ExecOptions(seed=0, verbose=0), callbacks=[clock])
        result["run_seconds"] = round(time.perf_counter() - start, 1)
        result["run_fps_overall"] = run.summary["fps"]
    result["train_fps"] = round(clock.fps, 1)
    result["train_steps_measured"] = clock.n1 - clock.n0
    result["train_fps_per_cpu_second"] = round(clock.fps_per_cpu_second, 1)
    result["hours_for_10M_steps_one_free_core"] = round(PUBLISHED_BUDGET / clock.fps_per_cpu_second / 3600, 1)
    hours = PUBLISHED_BUDGET / clock.fps / 3600
    result["hours_for_10M_steps"] = round(hours, 1)
    result["days_for_10M_steps"] = round(hours / 24, 2)
    result["peak_rss_gib_short_run"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, 3)
    result["default_buffer"] = default_buffer_bytes()
    result["load_avg_after"] = list(os.getloadavg())
    result["torch_threads"] = torch.get_num_threads()
    result["cpu_count"] = os.cpu_count()
    return result


def build_parser() -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run pong``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}",
                                     description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--warmup-steps", type=int, default=1000, help="learning_starts of the short run")
    parser.add_argument("--train-steps", type=int, default=4000, help="steps measured after learning_starts")
    parser.add_argument("--env-steps", type=int, default=3000, help="steps of the env-only measurement")
    parser.add_argument("--keep-throughput", action="store_true",
                        help="keep the recorded short benchmark instead of measuring it")
    parser.add_argument("--report", type=Path, default=None, metavar="RUN_DIR",
                        help="the long run's dir: its curve and table (default: keep the recorded long run)")
    parser.add_argument("--rss-log", type=Path, default=None, help="'<unix time> <rss KiB>' lines of the long run")
    parser.add_argument("--previous", type=Path, default=RESULTS_DIR / RESULTS_NAME,
                        help="results file whose parts not measured now are kept")
    parser.add_argument("--png", type=Path, default=RESULTS_DIR / PNG_NAME, help="where --report draws the curve")
    return parser


def _portable(argv: Sequence[str]) -> list[str]:
    """``argv`` with the paths of this machine replaced by placeholders."""
    names = {"--report": "RUN_DIR", "--rss-log": "RSS_LOG"}
    out = []
    for i, a in enumerate(argv):
        prev = argv[i - 1] if i else ""
        if prev in ("--previous", "--png") or a in ("--previous", "--png"):
            continue
        out.append(names.get(prev, a))
    return out


def run(argv: Sequence[str]) -> dict[str, Any]:
    """``python -m benchmarks run pong [OPTIONS]``: the short benchmark and/or the long run's report; the part not
    measured is kept from ``--previous``."""
    args = build_parser().parse_args(list(argv))
    needs_previous = args.keep_throughput or args.report is None
    previous = load_results(args.previous) if needs_previous else {}
    command = " ".join(["python -m benchmarks run", SECTION, *recorded_argv(_portable(list(argv)))])
    results: dict[str, Any] = {"command": previous.get("command", command)}
    if args.keep_throughput:
        results["throughput"] = previous["throughput"]
    else:
        results["throughput"] = throughput(args.warmup_steps, args.train_steps, args.env_steps)
        results["throughput"]["command"] = command
    if args.report is None:
        results["long_run"] = previous["long_run"]
    else:
        results["long_run"] = long_run(args.report, args.png, args.rss_log)
        results["command"] = command
    return results


BENCHMARKS = (
    Benchmark(name=SECTION, kind="speed", results=RESULTS_NAME,
              summary="Pong DQN: env and training steps/s, buffer memory and a (short) 1-seed learning curve",
              run=run, render=markdown),
)
