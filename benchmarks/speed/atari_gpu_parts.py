"""Parts of :mod:`benchmarks.speed.atari_gpu`: the GPU sampler, the learning curve (points, stats, plot) and the
``atari-gpu`` section rendered from the results alone."""

from __future__ import annotations

import shutil
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from benchmarks.report import save_figure

SECTION = "atari-gpu"
JSON_NAME, PNG_NAME = "atari_gpu.json", "atari_gpu_curve.png"
TARGET = 18.0  # the aim: Pong above +18
ROLLING = 20  # games in the rolling mean of the curve
ENV_ID = "PongNoFrameskip-v4"
#: The command as the results record it (its arguments follow, ``--out``'s folder as ``$OUT``).
COMMAND = f"python3 -m benchmarks run {SECTION}"


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
    save_figure(fig, path)


def _fmt_gpu(window: dict[str, float] | None) -> str:
    return "-" if not window else f"{window['util_mean']:.0f}% (max {window['util_max']:.0f}%)"


def markdown(data: dict[str, Any]) -> str:
    """The ``atari-gpu`` section of BENCHMARKS.md from the results of :func:`run`."""
    m = data["machine"]
    command = " ".join([COMMAND, *data.get("argv", [])])
    lines = ["## Pong on EnvPool in one command on a GPU machine", "",
             f"Command (on the device, after installing the wheels): `{command}`; {m['gpu'] or m['device']}, "
             f"{m['cores']} cores ({m['cpu']}), Python {m['python']}, torch {m['torch']}, envpool {m['envpool']}, "
             f"SB3 {m['stable_baselines3']}; {m['date']}; {data['seconds']:.0f} s in all "
             f"(budget {data['budget_s']:.0f} s); GPU utilisation from {data.get('gpu_source') or 'nothing'}. "
             "The results file comes back from the device as `benchmarks/results/atari_gpu.json`; "
             f"`python -m benchmarks render {SECTION}` renders it.", ""]
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
