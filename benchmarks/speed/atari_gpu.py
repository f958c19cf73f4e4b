"""One command on a GPU machine: Pong with PPO on EnvPool, its fps, GPU utilisation and learning curve.

::

    python -m benchmarks run atari-gpu --out DIR         # one GPU + 16 cores: ~8 min (--budget-s 470)
    python -m benchmarks run --output '' --results DIR/r.json atari-gpu --out DIR --device cpu --tiny --budget-s 90
    python -m benchmarks render atari-gpu                 # the section from benchmarks/results/atari_gpu.json

Phases; ``DIR/atari_gpu.json`` is rewritten as each ends, so a failure keeps what was measured before it:

1. ``compare`` (the plain path against EnvPool, one round): env-only steps/s and PPO training fps with the
   ``PongNoFrameskip-v4`` entry at 16 envs on DummyVecEnv, SubprocVecEnv (both ``AtariWrapper`` + frame stack) and
   EnvPool, and EnvPool at 32 envs with batch 512: the larger-batch speed trick, kept for phase 2 only if its fps
   is at least :data:`TRICK_MIN_GAIN` times the 16-env EnvPool run's;
2. ``learn``: PPO on EnvPool through ``train_sb3`` (the CLI's code path) until the budget's deadline; its
   ``n_timesteps`` is 1.3x what the fps measured in phase 1 gives until then (the linear learning-rate schedule is
   then at ~1/4 of its start at the deadline, and a faster run does not stop early). The learning curve comes from
   the run's monitor files (whole games, unclipped scores);
3. ``eval``: 16 greedy games on EnvPool, and ``train_sb3``'s final evaluation: greedy games on the plain ALE env
   (``AtariWrapper``), as ``python -m sbagents.evaluate`` plays them.

GPU utilisation is sampled with ``nvidia-smi`` every 0.5 s (``torch.cuda.utilization`` where nvidia-smi is
missing) and averaged over each measurement. Writes ``atari_gpu.json`` and ``atari_gpu_curve.png`` into ``--out``.
Imports only what the GPU machine gets: the project's source tree, SB3, sb3-contrib, Gymnasium, ale-py, EnvPool,
pettingzoo and tqdm wheels, and the machine's own torch, numpy and matplotlib.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import signal
import time
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback

from benchmarks.harness import Benchmark
from benchmarks.report import RESULTS_DIR, atomic_write_bytes, cpu_model
from benchmarks.speed.atari_gpu_parts import (
    JSON_NAME,
    PNG_NAME,
    SECTION,
    TARGET,
    GpuSampler,
    curve_points,
    curve_stats,
    markdown,
    plot_curve,
)
from benchmarks.speed.atari_speed import ENV_ID, env_rate, ppo_params, train_clock

#: The larger-batch run must be this much faster than the entry's 16 envs to be used for learning.
TRICK_MIN_GAIN = 1.3
EVAL_RESERVE_S = 75.0  # kept for phase 3 and the files (GPU sizes; the CPU smoke run scales it): one greedy game of a
#: half-trained Pong agent on the plain ALE env took ~28 s on the H200 machine, 16 on EnvPool about as long


class Deadline(BaseCallback):
    """Ends ``learn`` at ``deadline`` (``time.perf_counter``); records when learning started and stopped."""

    def __init__(self, deadline: float) -> None:
        super().__init__()
        self.deadline = deadline
        self.t0: float | None = None
        self.t1: float | None = None

    def _on_training_start(self) -> None:
        self.t0 = time.perf_counter()

    def _on_step(self) -> bool:
        return time.perf_counter() < self.deadline

    def _on_training_end(self) -> None:
        self.t1 = time.perf_counter()


class Progress(BaseCallback):
    """Every ``every_s`` seconds: steps, fps and the mean score of SB3's last 100 games, printed and kept in
    ``log`` (which the phase saves into the results), so a run cut short still shows how far it got."""

    def __init__(self, every_s: float, log: list[dict[str, Any]], save: Callable[[], None]) -> None:
        super().__init__()
        self.every_s, self.log, self.save = every_s, log, save
        self.start = self.last = 0.0

    def _on_training_start(self) -> None:
        self.start = self.last = time.perf_counter()

    def _on_step(self) -> bool:
        now = time.perf_counter()
        if now - self.last >= self.every_s:
            self.last = now
            games = [float(e["r"]) for e in self.model.ep_info_buffer or []]
            row = {"seconds": round(now - self.start, 1), "steps": int(self.num_timesteps),
                   "fps": round(self.num_timesteps / max(now - self.start, 1e-9)),
                   "mean_last_100_games": round(float(np.mean(games)), 2) if games else None}
            self.log.append(row)
            print(f"learn: {row}", flush=True)
            self.save()
        return True


class Results:
    """The JSON results, rewritten into ``out/atari_gpu.json`` after each phase."""

    def __init__(self, out: Path, data: dict[str, Any]) -> None:
        self.path = out / JSON_NAME
        self.data = data

    def save(self) -> None:
        """Write the file (temporary name, then renamed)."""
        atomic_write_bytes(self.path, (json.dumps(self.data, indent=1) + "\n").encode())


def _phase(results: Results, name: str, fn: Callable[[], Any]) -> Any:
    """Run phase ``fn``; its time and any error (with traceback on stderr) go into the results, then saved."""
    start = time.perf_counter()
    print(f"\n=== {name} ===", flush=True)
    try:
        value = fn()
    except Exception as exc:  # noqa: BLE001 - later phases still run
        traceback.print_exc()
        results.data.setdefault("errors", []).append(f"{name}: {type(exc).__name__}: {exc}")
        value = None
    results.data.setdefault("phase_seconds", {})[name] = round(time.perf_counter() - start, 1)
    results.save()
    return value


def compare(results: Results, sampler: GpuSampler, device: str, tiny: bool, until: float) -> dict[str, Any]:
    """Phase 1: env-only and PPO fps of the plain vec envs and EnvPool (one round), and the larger-batch trick.
    PPO runs that would start after ``until`` (``time.perf_counter``) are left out."""
    n_envs, big = (4, 8) if tiny else (16, 32)
    env_steps, rollouts, n_steps = (500, 1, 32) if tiny else (8000, 4, 128)
    out: dict[str, Any] = {"n_envs": n_envs, "env": {}, "ppo": {}}
    results.data["compare"] = out
    for kind in ("dummy", "subproc", "envpool"):
        out["env"][kind] = round(env_rate(kind, n_envs, env_steps))
        print(f"env only {kind} x{n_envs}: {out['env'][kind]:,} steps/s", flush=True)
    runs = [(kind, kind, ppo_params(n_envs, n_steps)) for kind in ("envpool", "subproc", "dummy")]
    runs.insert(1, (f"envpool_x{big}", "envpool", ppo_params(big, n_steps)))
    for name, kind, params in runs:
        if time.perf_counter() > until:
            print(f"PPO {name}: left out (phase 1's share of the budget is spent)", flush=True)
            continue
        rollout = params["n_envs"] * params["n_steps"]
        clock = train_clock("ppo", kind, params, rollout, rollouts * rollout, device)
        out["ppo"][name] = {"fps": round(clock.fps), "rollout_fps": round(clock.rollout_fps),
                            **{k: params[k] for k in ("n_envs", "batch_size")}}
        sampler.track(f"ppo_{name}", clock.t0, clock.t1)
        print(f"PPO {name}: {clock.fps:,.0f} steps/s (n_envs {params['n_envs']}, batch {params['batch_size']})",
              flush=True)
        results.save()
    ratios = {"env_envpool/dummy": (out["env"], "envpool", "dummy"),
              "env_envpool/subproc": (out["env"], "envpool", "subproc"),
              "ppo_envpool/dummy": (out["ppo"], "envpool", "dummy"),
              "ppo_envpool/subproc": (out["ppo"], "envpool", "subproc"),
              f"ppo_envpool_x{big}/envpool": (out["ppo"], f"envpool_x{big}", "envpool")}

    def rate(table: dict[str, Any], key: str) -> float:
        value = table[key]
        return float(value["fps"] if isinstance(value, dict) else value)

    out["ratios"] = {name: round(rate(t, a) / rate(t, b), 3) for name, (t, a, b) in ratios.items()
                     if a in t and b in t}
    return out


def choose(compare_out: dict[str, Any] | None, tiny: bool) -> dict[str, Any]:
    """The PPO overrides of phase 2: the entry's envs, or the larger batch where it paid
    (:data:`TRICK_MIN_GAIN`)."""
    n_envs = 4 if tiny else 16
    ppo = (compare_out or {}).get("ppo") or {}
    big = next((k for k in ppo if k.startswith("envpool_x")), None)
    if "envpool" not in ppo or big is None:
        fps = ppo["envpool"]["fps"] if "envpool" in ppo else None
        return {"params": ppo_params(n_envs), "fps": fps, "reason": "phase 1 incomplete: the entry's settings"}
    gain = ppo[big]["fps"] / ppo["envpool"]["fps"]
    if gain >= TRICK_MIN_GAIN:
        params = {k: ppo[big][k] for k in ("n_envs", "batch_size")}
        return {"params": {**params, "n_steps": 128}, "fps": ppo[big]["fps"],
                "reason": f"{big}: {gain:.2f}x the fps of {n_envs} envs (>= {TRICK_MIN_GAIN}x): kept"}
    return {"params": ppo_params(n_envs), "fps": ppo["envpool"]["fps"],
            "reason": f"{big}: {gain:.2f}x the fps of {n_envs} envs (< {TRICK_MIN_GAIN}x): the entry's {n_envs} envs"}


def learn(results: Results, sampler: GpuSampler, device: str, seed: int, deadline: float, choice: dict[str, Any],
          tiny: bool, work: Path) -> Any:
    """Phase 2: PPO on EnvPool until ``deadline``; returns ``train_sb3``'s result (its final evaluation included)."""
    from sbagents.core.options import EvalOptions, ExecOptions, OutputOptions, Sb3Options, TrainSpec
    from sbagents.pipeline.training import train_sb3

    params = dict(choice["params"])
    seconds = max(deadline - time.perf_counter(), 1.0)
    fps = choice["fps"] or (5000.0 if device != "cpu" else 100.0)
    rollout = params["n_envs"] * params["n_steps"]
    n_timesteps = max(int(fps * seconds * 1.3) // rollout + 1, 2) * rollout  # the deadline ends it first
    if tiny:
        params.update(n_steps=32, batch_size=64)
    info: dict[str, Any] = {"params": params, "planned_timesteps": n_timesteps, "planned_seconds": round(seconds)}
    results.data["learn"] = info
    results.save()
    print(f"PPO {params} for {n_timesteps:,} steps or until the deadline ({seconds:.0f} s)", flush=True)
    stop = Deadline(deadline)
    progress = Progress(5.0 if tiny else 30.0, info.setdefault("progress", []), results.save)
    result = train_sb3(TrainSpec("ppo", ENV_ID, n_timesteps=n_timesteps, hyperparams=params),
                       OutputOptions(log_folder=str(work)),
                       EvalOptions(eval_freq=0, final_eval_episodes=1),
                       ExecOptions(seed=seed, device=device, num_threads=1, progress=False, verbose=1),
                       callbacks=[stop, progress], sb3=Sb3Options(vec_env="envpool", log_interval=10))
    wall = (stop.t1 or time.perf_counter()) - (stop.t0 or time.perf_counter())
    sampler.track("learn", stop.t0, stop.t1)
    assert result.model is not None, "an SB3 run of one algorithm returns its model"
    info.update(steps=int(result.model.num_timesteps), seconds=round(wall, 1),
                fps=round(result.model.num_timesteps / max(wall, 1e-9)),
                curve=curve_points(result.run_dir),
                final_eval_ale=result.summary.get("eval"))
    info.update(curve_stats(info["curve"]))
    return result


def evaluate_envpool(results: Results, model: Any, seed: int, tiny: bool) -> dict[str, Any]:
    """Phase 3: greedy games on EnvPool (one per env, in parallel)."""
    from stable_baselines3.common.evaluation import evaluate_policy

    from sbagents.core.env_names import resolve_env
    from sbagents.core.experiment import build_experiment
    from sbagents.core.options import TrainSpec
    from sbagents.env_factory import make_eval_vec

    n = 4 if tiny else 16
    ref = resolve_env(ENV_ID)
    exp = build_experiment(TrainSpec("ppo", ENV_ID), ref)
    venv = make_eval_vec(exp, ref, n, seed + 10_000, vec_env="envpool")
    try:
        returns, lengths = evaluate_policy(model, venv, n_eval_episodes=n, deterministic=True,
                                           return_episode_rewards=True)
    finally:
        venv.close()
    assert isinstance(returns, list), "return_episode_rewards=True: one return per game"
    out = {"n_games": n, "mean": float(np.mean(returns)), "std": float(np.std(returns)),
           "returns": [float(r) for r in returns], "mean_frames": float(np.mean(lengths))}
    results.data["eval_envpool"] = out
    return out


def machine(device: str) -> dict[str, Any]:
    """CPU, cores, GPU, versions, date."""
    from importlib.metadata import version

    gpu = torch.cuda.get_device_name(0) if device.startswith("cuda") and torch.cuda.is_available() else None
    versions: dict[str, str | None] = {}
    for name in ("envpool", "stable_baselines3", "ale_py", "gymnasium"):
        try:
            versions[name] = version(name)
        except Exception:  # noqa: BLE001 - not installed
            versions[name] = None
    return {"cpu": cpu_model(), "cores": os.cpu_count(), "gpu": gpu, "device": device,
            "python": platform.python_version(), "torch": torch.__version__, "numpy": np.__version__, **versions,
            "date": time.strftime("%Y-%m-%d %H:%M"), "load_before": round(os.getloadavg()[0], 2)}


def run(out: Path, budget_s: float, device: str, seed: int, tiny: bool, argv: list[str] | None = None
        ) -> dict[str, Any]:
    """All phases within ``budget_s`` seconds from now; returns the results (also in ``out/atari_gpu.json``).

    :param argv: the command's arguments, recorded (``--out``'s folder as ``$OUT``).
    """
    given = argv or []
    argv = [("$OUT" if i and given[i - 1] == "--out" else a) for i, a in enumerate(given)]
    start = time.perf_counter()
    deadline_all = start + budget_s
    out.mkdir(parents=True, exist_ok=True)
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    torch.set_num_threads(1)
    results = Results(out, {"machine": machine(device), "budget_s": budget_s, "seed": seed, "tiny": tiny,
                            "target": TARGET, "argv": argv})
    results.save()
    sampler = GpuSampler()
    results.data["gpu_source"] = sampler.source
    work = Path(os.environ.get("TMPDIR", "/tmp")) / f"sbagents-atari-gpu-{os.getpid()}"
    previous = signal.signal(signal.SIGTERM, _interrupt)  # a `timeout` still saves what was measured

    def after_phase() -> None:  # the GPU figures so far (samples still on their way are left out), saved
        results.data["gpu"] = sampler.summary()
        results.save()

    try:
        until = start + 0.4 * budget_s
        compared = _phase(results, "compare", lambda: compare(results, sampler, device, tiny, until))
        after_phase()
        choice = choose(compared, tiny)
        results.data["choice"] = choice
        print(choice["reason"], flush=True)
        reserve = EVAL_RESERVE_S * (0.6 if tiny else 1.0)
        trained = _phase(results, "learn", lambda: learn(results, sampler, device, seed, deadline_all - reserve,
                                                        choice, tiny, work))
        after_phase()
        learned = results.data.get("learn") or {}
        plot_curve(learned.get("curve") or [], out / PNG_NAME,
                   f"PPO {ENV_ID} on EnvPool, {learned.get('steps', 0):,} steps in {learned.get('seconds', 0):.0f} s"
                   f" ({results.data['machine']['gpu'] or device})")
        if trained is not None:
            _phase(results, "eval", lambda: evaluate_envpool(results, trained.model, seed, tiny))
    except KeyboardInterrupt:
        results.data.setdefault("errors", []).append("interrupted (SIGTERM or Ctrl-C): later phases did not run")
    finally:
        signal.signal(signal.SIGTERM, previous)
        sampler.close()
        results.data["gpu"] = sampler.summary()
        shutil.rmtree(work, ignore_errors=True)
        results.data["seconds"] = round(time.perf_counter() - start, 1)
        results.data["machine"]["load_after"] = round(os.getloadavg()[0], 2)
        results.save()
    print(f"\nwrote {out / JSON_NAME} and {out / PNG_NAME} in {results.data['seconds']:.0f} s", flush=True)
    return results.data


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def run_cli(argv: Sequence[str]) -> dict[str, Any]:
    """``python -m benchmarks run atari-gpu --out DIR [OPTIONS]``: run the phases (files in ``DIR`` as each ends),
    copy the curve into ``benchmarks/results/`` and return the results."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", required=True, help="folder for atari_gpu.json and atari_gpu_curve.png")
    parser.add_argument("--budget-s", type=float, default=470.0, help="seconds for all phases (default 470)")
    parser.add_argument("--device", default="auto", help="torch device (auto: cuda if available)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tiny", action="store_true", help="4 envs and tiny measurements (the CPU smoke run)")
    args = parser.parse_args(list(argv))
    if args.budget_s < 30:
        parser.error("--budget-s must be >= 30")
    data = run(Path(args.out), args.budget_s, args.device, args.seed, args.tiny, list(argv))
    png = Path(args.out) / PNG_NAME
    if png.exists() and png.resolve() != (RESULTS_DIR / PNG_NAME).resolve():
        atomic_write_bytes(RESULTS_DIR / PNG_NAME, png.read_bytes())
    return data


BENCHMARKS = (
    Benchmark(name=SECTION, kind="speed", results=JSON_NAME,
              summary="Pong PPO on EnvPool on a GPU machine: fps side by side, GPU busy, learning curve",
              run=run_cli, render=markdown),
)
