"""DQN on PongNoFrameskip-v4 through the sbagents CLI's code path: throughput and replay-buffer memory.

Measures on this machine (1 torch thread):

- ``env_fps``: agent steps/s of the wrapped env alone (AtariWrapper + 4-frame stack, random actions);
- ``train_fps``: agent steps/s of ``sbagents.pipeline.training.train`` with the ``atari`` zoo entry *after*
  ``learning_starts`` (one gradient step of batch 32 every 4 steps, as in the 10M-step recipe);
- the hours 10M steps (the budget of the published +20.6) would take at ``train_fps``;
- the bytes of the default replay buffer (1e5 transitions, ``optimize_memory_usage``) and the process's
  peak RSS during the short run.

Usage::

    python -m benchmarks.speed.pong_throughput --warmup-steps 1000 --train-steps 4000 \
        --out benchmarks/results/pong_throughput.json
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import resource
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecTransposeImage

from sbagents.api import EvalOptions, ExecOptions, OutputOptions, TrainSpec, train
from sbagents.core.env_names import resolve_env
from sbagents.core.experiment import build_experiment
from sbagents.env_factory import make_vec

ENV_ID = "PongNoFrameskip-v4"
PUBLISHED_BUDGET = 10_000_000


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


def report(
    run_dir: Path, md_path: Path, png_path: Path, throughput: Path | None, rss_log: Path | None
) -> str:
    """Write the learning curve PNG and a markdown table of a (possibly still running) Pong run."""
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
    lines = [
        "| timesteps | wall time (min) | eval return (mean +- std, 5 games) "
        "| training return (last 10 games) |",
        "|---:|---:|---:|---:|",
    ]
    with np.load(run_dir / "evaluations.npz") as data:
        ev_steps, results = data["timesteps"], data["results"]
    for step, res in zip(ev_steps, results, strict=True):
        minutes = float(np.interp(step, steps, seconds)) / 60
        done = curve.returns[steps <= step][-10:]
        train_txt = f"{done.mean():.1f}" if len(done) else "-"
        lines.append(f"| {int(step):,} | {minutes:.0f} | {res.mean():.1f} +- {res.std():.1f} | {train_txt} |")
    fps = (steps[-1] - steps[0]) / max(seconds[-1] - seconds[0], 1e-9)
    after = steps > 100_000
    fps_learning = float("nan")
    if after.sum() > 1:
        fps_learning = (steps[after][-1] - steps[after][0]) / max(
            seconds[after][-1] - seconds[after][0], 1e-9
        )
    facts = [
        f"- reached {int(steps[-1]):,} steps ({len(curve.returns)} games) in {seconds[-1] / 60:.0f} min;",
        f"  {fps:.0f} steps/s overall, {fps_learning:.0f} steps/s once learning started (after 100k steps)",
        f"- training return over the last 10 games: {curve.returns[-10:].mean():.1f}",
    ]
    if rss_log is not None and rss_log.exists():
        rss = np.loadtxt(rss_log, ndmin=2)
        facts.append(
            f"- peak RSS of the training process: {rss[:, 1].max() / 2**20:.2f} GiB "
            f"(sampled every 30 s; the replay buffer is full from step 100,000 on)"
        )
    if throughput is not None and throughput.exists():
        tp = json.loads(throughput.read_text())
        facts.append(
            f"- benchmark (not niced, {tp['train_steps_measured']} learning steps): {tp['train_fps']} "
            f"steps/s wall, {tp['train_fps_per_cpu_second']} per CPU-second; 10M steps: "
            f"{tp['hours_for_10M_steps']} h at that wall rate, {tp['hours_for_10M_steps_one_free_core']} h "
            f"on one free core; env alone {tp['env_fps']} steps/s; load average "
            f"{tp['load_avg_before'][0]:.1f} on {tp['cpu_count']} cores"
        )
    command = (run_dir / "command.txt").read_text().strip() if (run_dir / "command.txt").exists() else "?"
    head = [
        f"# DQN on {ENV_ID}: throughput and a (short) learning curve",
        "",
        "Written by `python -m benchmarks.speed.pong_throughput --report RUN_DIR --rss-log RSS_LOG` from the run's",
        "monitor files and `evaluations.npz`; curve: `pong_dqn_curve.png`; short benchmark:",
        "`pong_throughput.json`.",
        f"Run: `nice -n 19 nohup {command}` (RL Zoo's `atari` entry: AtariWrapper, 4-frame stack, CnnPolicy,",
        "1e5 buffer with optimize_memory_usage, learning_starts 1e5, exploration over the first 1e6 steps).",
        "Published with this recipe: +20.6 +- 0.6 after 1e7 steps. Timings on a shared, loaded 2-core CPU",
        "(3-4 other engineers' jobs; the long run was niced to 19, so it got what the others left).",
        "",
    ]
    text = "\n".join(head + facts) + "\n\n" + "\n".join(lines) + "\n"
    md_path.write_text(text)
    return text


def main() -> None:
    """Run the measurements and write a JSON file."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--warmup-steps", type=int, default=1000, help="learning_starts of the short run")
    parser.add_argument("--train-steps", type=int, default=4000, help="steps measured after learning_starts")
    parser.add_argument("--env-steps", type=int, default=3000, help="steps of the env-only measurement")
    parser.add_argument("--out", default="benchmarks/results/pong_throughput.json")
    parser.add_argument(
        "--report",
        type=Path,
        default=None,
        metavar="RUN_DIR",
        help="instead: write the curve and table of a long run (see --md, --png)",
    )
    parser.add_argument("--md", type=Path, default=Path("benchmarks/results/pong.md"))
    parser.add_argument("--png", type=Path, default=Path("benchmarks/results/pong_dqn_curve.png"))
    parser.add_argument("--rss-log", type=Path, default=None, help="'<unix time> <rss KiB>' lines")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.report is not None:
        print(report(args.report, args.md, args.png, Path(args.out), args.rss_log))
        return

    result: dict[str, Any] = {"env": ENV_ID, "load_avg_before": list(os.getloadavg())}
    result["env_fps"] = round(env_fps(args.env_steps), 1)
    clock = StepClock(args.warmup_steps)
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        spec = TrainSpec("dqn", ENV_ID, args.warmup_steps + args.train_steps,
                         {"buffer_size": 10_000, "learning_starts": args.warmup_steps})
        run = train(spec, OutputOptions(tmp), EvalOptions(eval_freq=-1, final_eval_episodes=0),
                    ExecOptions(seed=0, verbose=0),
                    callbacks=[clock])
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
    text = json.dumps(result, indent=2)
    print(text)
    if args.out:
        os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
        with open(args.out, "w") as fh:
            fh.write(text + "\n")


if __name__ == "__main__":
    main()
