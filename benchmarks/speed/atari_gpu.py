"""One command on a GPU machine: Pong with PPO on EnvPool, its fps, GPU utilisation and learning curve.

::

    python -m benchmarks.atari_gpu --out DIR                    # one GPU + 16 cores: ~8 min (--budget-s 470)
    python -m benchmarks.atari_gpu --out DIR --device cpu --tiny --budget-s 90   # smoke run on a CPU
    python -m benchmarks.atari_gpu --render DIR/atari_gpu.json  # BENCHMARKS.md section atari-gpu (+ results files)

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
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback

from benchmarks.speed.atari_speed import ENV_ID, cpu_name, env_rate, ppo_params, train_clock

SECTION = "atari-gpu"
JSON_NAME, PNG_NAME = "atari_gpu.json", "atari_gpu_curve.png"
#: The larger-batch run must be this much faster than the entry's 16 envs to be used for learning.
TRICK_MIN_GAIN = 1.3
TARGET = 18.0  # the aim: Pong above +18
ROLLING = 20  # games in the rolling mean of the curve
EVAL_RESERVE_S = 75.0  # kept for phase 3 and the files (GPU sizes; the CPU smoke run scales it): one greedy game of a
#: half-trained Pong agent on the plain ALE env took ~28 s on the H200 machine, 16 on EnvPool about as long


class GpuSampler:
    """GPU utilisation (%) and memory (MiB) every ``interval_ms`` from ``nvidia-smi`` (else torch), in a thread.

    nvidia-smi stamps each sample itself (its output may reach us in buffered chunks), so measurements register
    their time spans with :meth:`track` and get their figures from :meth:`summary` after :meth:`close`.
    """

    def __init__(self, interval_ms: int = 500) -> None:
        self.samples: list[tuple[float, float, float]] = []  # (perf_counter, util %, memory MiB)
        self.source: str | None = None
        self.spans: dict[str, tuple[float, float]] = {}
        self._offset = time.time() - time.perf_counter()
        self._stop = threading.Event()
        self._proc: subprocess.Popen[str] | None = None
        self._reader: threading.Thread | None = None
        exe = shutil.which("nvidia-smi")
        if exe is not None:
            self._proc = subprocess.Popen(
                [exe, "--query-gpu=timestamp,utilization.gpu,memory.used", "--format=csv,noheader,nounits",
                 "-lms", str(interval_ms)], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
            self.source = "nvidia-smi"
            self._reader = threading.Thread(target=self._read_smi, daemon=True)
        elif torch.cuda.is_available():
            try:
                torch.cuda.utilization()
            except Exception:  # noqa: BLE001 - pynvml missing: no source
                return
            self.source = "torch.cuda.utilization"
            self._reader = threading.Thread(target=self._poll_torch, args=(interval_ms / 1000,), daemon=True)
        if self._reader is not None:
            self._reader.start()

    def _read_smi(self) -> None:
        from datetime import datetime

        assert self._proc is not None and self._proc.stdout is not None
        for line in self._proc.stdout:
            parts = [p.strip() for p in line.split(",")]
            try:
                stamp = datetime.strptime(parts[0], "%Y/%m/%d %H:%M:%S.%f").timestamp() - self._offset
                self.samples.append((stamp, float(parts[1]), float(parts[2])))
            except (ValueError, IndexError):
                continue

    def _poll_torch(self, interval: float) -> None:
        while not self._stop.wait(interval):
            self.samples.append((time.perf_counter(), float(torch.cuda.utilization()),
                                 torch.cuda.memory_reserved() / 2**20))

    def track(self, name: str, t0: float | None, t1: float | None) -> None:
        """Register the span ``t0..t1`` (``time.perf_counter``) of measurement ``name``."""
        if t0 is not None and t1 is not None:
            self.spans[name] = (t0, t1)

    def window(self, t0: float, t1: float) -> dict[str, float] | None:
        """Mean / max utilisation and max memory of the samples between ``t0`` and ``t1`` (None: no samples)."""
        inside = [(u, m) for t, u, m in list(self.samples) if t0 <= t <= t1]
        if not inside:
            return None
        util = np.array([u for u, _ in inside])
        return {"util_mean": round(float(util.mean()), 1), "util_max": float(util.max()),
                "memory_max_mib": float(max(m for _, m in inside)), "samples": len(inside)}

    def summary(self) -> dict[str, dict[str, float] | None]:
        """The figures of every tracked span (after :meth:`close`, every sample has arrived)."""
        return {name: self.window(t0, t1) for name, (t0, t1) in self.spans.items()}

    def close(self) -> None:
        """Stop sampling and wait for the samples still on their way."""
        self._stop.set()
        if self._proc is not None:
            self._proc.terminate()
            self._proc.wait(timeout=5)
        if self._reader is not None:
            self._reader.join(timeout=5)


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


def _atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


class Results:
    """The JSON results, rewritten into ``out/atari_gpu.json`` after each phase."""

    def __init__(self, out: Path, data: dict[str, Any]) -> None:
        self.path = out / JSON_NAME
        self.data = data

    def save(self) -> None:
        """Write the file (temporary name, then renamed)."""
        _atomic_write(self.path, (json.dumps(self.data, indent=1) + "\n").encode())


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
        params = {k: compare_out["ppo"][big][k] for k in ("n_envs", "batch_size")}
        return {"params": {**params, "n_steps": 128}, "fps": compare_out["ppo"][big]["fps"],
                "reason": f"{big}: {gain:.2f}x the fps of {n_envs} envs (>= {TRICK_MIN_GAIN}x): kept"}
    return {"params": ppo_params(n_envs), "fps": compare_out["ppo"]["envpool"]["fps"],
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
    info.update(steps=int(result.model.num_timesteps), seconds=round(wall, 1),
                fps=round(result.model.num_timesteps / max(wall, 1e-9)),
                curve=curve_points(result.run_dir),
                final_eval_ale=result.summary.get("eval"))
    info.update(curve_stats(info["curve"]))
    return result


def curve_points(run_dir: Path) -> list[list[float]]:
    """``[timestep, minutes since the start, game score]`` of every training game, in the order they ended."""
    from sbagents.core.monitor_files import read_monitor_files
    from sbagents.visualize.curves import load_run_curve

    curve = load_run_curve(run_dir, ENV_ID)
    episodes = read_monitor_files(run_dir)
    start = episodes.t_start if episodes.t_start is not None else 0.0
    minutes = (episodes.end_times - start) / 60.0
    return [[int(t), round(float(m), 3), float(r)] for t, m, r in zip(curve.timesteps, minutes, curve.returns,
                                                                      strict=False)]


def curve_stats(points: list[list[float]]) -> dict[str, Any]:
    """Rolling mean (:data:`ROLLING` games) at the end, its best, and when it first reached :data:`TARGET`."""
    if not points:
        return {"games": 0}
    returns = np.array([p[2] for p in points])
    k = min(ROLLING, len(returns))
    rolling = np.convolve(returns, np.ones(k) / k, mode="valid")
    reached = np.flatnonzero(rolling >= TARGET)
    first = None if not len(reached) else points[int(reached[0]) + k - 1]
    return {"games": len(points), "rolling_games": k, "final_rolling_mean": round(float(rolling[-1]), 2),
            "best_rolling_mean": round(float(rolling.max()), 2),
            "reached_target_at": None if first is None else {"timestep": first[0], "minutes": first[1]}}


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
    out = {"n_games": n, "mean": float(np.mean(returns)), "std": float(np.std(returns)),
           "returns": [float(r) for r in returns], "mean_frames": float(np.mean(lengths))}
    results.data["eval_envpool"] = out
    return out


def plot_curve(points: list[list[float]], path: Path, title: str) -> None:
    """Training game scores (dots) and their rolling mean against timesteps, the +18 aim dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=100)
    if points:
        steps = np.array([p[0] for p in points])
        returns = np.array([p[2] for p in points])
        ax.scatter(steps, returns, s=4, alpha=0.3, label="training game")
        k = min(ROLLING, len(returns))
        rolling = np.convolve(returns, np.ones(k) / k, mode="valid")
        ax.plot(steps[k - 1:], rolling, lw=2, label=f"mean of {k} games")
    ax.axhline(TARGET, ls="--", color="grey", label=f"+{TARGET:g}")
    ax.set(xlabel="timesteps", ylabel="game score", ylim=(-21.5, 21.5), title=title)
    ax.legend(loc="lower right")
    fig.tight_layout()
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp)
    plt.close(fig)
    os.replace(tmp, path)


def machine(device: str) -> dict[str, Any]:
    """CPU, cores, GPU, versions, date."""
    from importlib.metadata import version

    gpu = torch.cuda.get_device_name(0) if device.startswith("cuda") and torch.cuda.is_available() else None
    versions = {}
    for name in ("envpool", "stable_baselines3", "ale_py", "gymnasium"):
        try:
            versions[name] = version(name)
        except Exception:  # noqa: BLE001 - not installed
            versions[name] = None
    return {"cpu": cpu_name(), "cores": os.cpu_count(), "gpu": gpu, "device": device,
            "python": platform.python_version(), "torch": torch.__version__, "numpy": np.__version__, **versions,
            "date": time.strftime("%Y-%m-%d %H:%M"), "load_before": round(os.getloadavg()[0], 2)}


def run(out: Path, budget_s: float, device: str, seed: int, tiny: bool, argv: list[str] | None = None
        ) -> dict[str, Any]:
    """All phases within ``budget_s`` seconds from now; returns the results (also in ``out/atari_gpu.json``).

    :param argv: the command's arguments, recorded (``--out``'s folder as ``$OUT``).
    """
    argv = [("$OUT" if i and argv[i - 1] == "--out" else a) for i, a in enumerate(argv or [])]
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


def _fmt_gpu(window: dict[str, float] | None) -> str:
    return "-" if not window else f"{window['util_mean']:.0f}% (max {window['util_max']:.0f}%)"


def markdown(data: dict[str, Any]) -> str:
    """The ``atari-gpu`` section of BENCHMARKS.md from the results of :func:`run`."""
    m = data["machine"]
    command = " ".join(["python3 -m benchmarks.atari_gpu", *data.get("argv", [])])
    lines = ["## Pong on EnvPool in one command on a GPU machine", "",
             f"Command (on the device, after installing the wheels): `{command}`; {m['gpu'] or m['device']}, "
             f"{m['cores']} cores ({m['cpu']}), Python {m['python']}, torch {m['torch']}, envpool {m['envpool']}, "
             f"SB3 {m['stable_baselines3']}; {m['date']}; {data['seconds']:.0f} s in all "
             f"(budget {data['budget_s']:.0f} s); GPU utilisation from {data.get('gpu_source') or 'nothing'}. "
             "Rendered by `python -m benchmarks.atari_gpu --render <atari_gpu.json>`.", ""]
    comp, gpu = data.get("compare") or {}, data.get("gpu") or {}
    if comp.get("ppo"):
        n = comp["n_envs"]
        lines += [f"Side by side ({n} envs; env-only: random actions, same preprocessing; PPO: the "
                  "`PongNoFrameskip-v4` entry, timed after one rollout; rollout: the collection phase alone):", "",
                  "| vec env | env-only steps/s | PPO steps/s | PPO rollout steps/s | GPU busy (PPO) |",
                  "|---|---:|---:|---:|---:|"]
        order = [k for k in ("dummy", "subproc", "envpool") if k in comp["ppo"]]
        for name, row in [(k, comp["ppo"][k]) for k in order + [k for k in comp["ppo"] if k not in order]]:
            kind = name if name in comp["env"] else None
            env = f"{comp['env'][kind]:,}" if kind else "-"
            label = name if kind else f"envpool, {row['n_envs']} envs, batch {row['batch_size']}"
            lines.append(f"| {label} | {env} | {row['fps']:,} | {row.get('rollout_fps', 0):,} | "
                         f"{_fmt_gpu(gpu.get(f'ppo_{name}'))} |")
        if comp.get("ratios"):
            lines += ["", "Ratios: " + ", ".join(f"{k} {v:.2f}x" for k, v in comp["ratios"].items()) + "."]
    choice = data.get("choice") or {}
    learned = data.get("learn") or {}
    if learned.get("steps"):
        reached = learned.get("reached_target_at")
        verdict = (f"the mean of {learned['rolling_games']} training games first reached +{TARGET:g} at "
                   f"{reached['timestep']:,} steps ({reached['minutes']:.1f} min)" if reached else
                   f"the mean of {learned.get('rolling_games', 0)} training games did not reach +{TARGET:g}")
        p = learned["params"]
        setting = f"{p['n_envs']} envs x {p['n_steps']} steps, batch {p['batch_size']}"
        lines += ["", f"Learning: {choice.get('reason', '')}. PPO ({setting}) trained {learned['steps']:,} "
                  f"steps in {learned['seconds']:.0f} s ({learned['fps']:,} steps/s overall, GPU "
                  f"{_fmt_gpu(gpu.get('learn'))}); {learned['games']} games; {verdict}; rolling mean at the end "
                  f"{learned.get('final_rolling_mean')}, best {learned.get('best_rolling_mean')}. "
                  f"At {learned['fps']:,} steps/s, RL Zoo's 10M-step budget would take "
                  f"{10_000_000 / learned['fps'] / 60:.0f} min."]
        ale = learned.get("final_eval_ale")
        ev = data.get("eval_envpool")
        if ev:
            lines.append(f"Greedy evaluation: EnvPool {ev['mean']:+.1f} +- {ev['std']:.1f} over {ev['n_games']} games"
                         + (f"; plain ALE env (AtariWrapper, as `evaluate` plays) {ale['mean_return']:+.1f} over "
                            f"{ale['n_episodes']} games." if ale else "."))
        lines += ["", f"![Pong PPO on EnvPool](benchmarks/results/{PNG_NAME})"]
    if data.get("errors"):
        lines += ["", "Errors: " + "; ".join(data["errors"])]
    if data.get("notes"):
        lines += ["", "Notes: " + " ".join(data["notes"])]
    return "\n".join(lines)


def render(json_path: Path, output: str, results_dir: Path) -> str:
    """Write the section into ``output`` and copy the JSON and PNG next to it into ``results_dir``."""
    from benchmarks.report import write_section

    data = json.loads(json_path.read_text())
    text = markdown(data)
    results_dir.mkdir(parents=True, exist_ok=True)
    _atomic_write(results_dir / JSON_NAME, json_path.read_bytes())
    png = json_path.with_name(PNG_NAME)
    if png.exists():
        _atomic_write(results_dir / PNG_NAME, png.read_bytes())
    if output:
        write_section(output, text, SECTION)
    print(text)
    return text


def main(argv: list[str] | None = None) -> int:
    """Run the phases (``--out``), or render a results file into BENCHMARKS.md (``--render``)."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.atari_gpu", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=None, help="folder for atari_gpu.json and atari_gpu_curve.png")
    parser.add_argument("--budget-s", type=float, default=470.0, help="seconds for all phases (default 470)")
    parser.add_argument("--device", default="auto", help="torch device (auto: cuda if available)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tiny", action="store_true", help="4 envs and tiny measurements (the CPU smoke run)")
    parser.add_argument("--render", default=None, metavar="JSON", help="write the section from a results file")
    parser.add_argument("--output", default="BENCHMARKS.md", help="Markdown file --render updates ('' = none)")
    parser.add_argument("--results-dir", default="benchmarks/results", help="where --render copies JSON and PNG")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.render is not None:
        render(Path(args.render), args.output, Path(args.results_dir))
        return 0
    if args.out is None:
        parser.error("--out DIR (or --render JSON) is required")
    if args.budget_s < 30:
        parser.error("--budget-s must be >= 30")
    data = run(Path(args.out), args.budget_s, args.device, args.seed, args.tiny,
               list(sys.argv[1:] if argv is None else argv))
    return 1 if data.get("errors") else 0


if __name__ == "__main__":
    raise SystemExit(main())
