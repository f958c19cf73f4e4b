"""Chapter 3's Pong on the reader's machine: PQN beside SB3's DQN and PPO, each given the same wall-clock budget on
this machine, scored by greedy games on the plain ALE env against training time.

Per (algo, seed): ``python -m sbagents.train --algo ALGO --env PongNoFrameskip-v4`` with the shipped zoo entry (PQN:
``zoo_configs/pqn.yml``'s ``atari`` entry, CleanRL's ``pqn_atari_envpool`` settings; DQN: RL Zoo's ``atari`` entry;
PPO: RL Zoo's Pong entry; EnvPool stepping the envs when installed), saving a checkpoint every ``--save-every`` env
steps, and stopped (Ctrl-C: it saves its model) once its training has had ``--budget-s`` seconds of wall time
(counted from its run dir's creation: imports excluded). Each run trains with ``--num-threads`` torch threads (2: both
cores of the project's machines; idle OpenMP threads sleep, see ``sbagents.openmp``). Then the model the run ends
with plays ``--games`` greedy games and every earlier checkpoint ``--curve-games`` (``python -m sbagents.evaluate``;
Pong's score is a game's return, -21 to +21), which makes the curve of score against training seconds.

Runs live in ``OUT/<algo>/seed<S>``. A run stopped before its budget (a session that ended) goes on from its latest
save (a stopped part's final model, else its last checkpoint) with ``train -i`` (DQN without its replay buffer,
which refills from ``learning_starts``); its parts' training seconds add up. Evaluations are kept per checkpoint
(``scores.json`` in the run's folder). The published results' rows of (algo, seed) pairs a command does not train
are kept (``--fresh``: not), so each algorithm can have the machine to itself in a session of its own::

    python -m benchmarks run pong-cpu -f OUT --algos pqn --seeds 0 [--budget-s 7200] [--games 10]

``pong-gpu`` is the same with a GPU's defaults: 10 minutes of training with ``--device cuda`` and 1 torch thread
(EnvPool uses every core), GPU utilisation sampled with ``nvidia-smi`` while each run trains (the ``GPU busy`` column;
the checkpoints are scored on the CPU), its own results file and section::

    python -m benchmarks run pong-gpu -f OUT --algos pqn          # one GPU with its CPU cores
    python -m benchmarks run --output '' --results OUT/r.json pong-gpu -f OUT --algos pqn --quick --device cpu
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from benchmarks.harness import Benchmark
from benchmarks.report import RESULTS_DIR, atomic_write_text, kept_rows, load_average, machine_info, save_figure
from benchmarks.stats import seed_stats, stats_bullets
from sbagents.core.run_dir import CHECKPOINT_PREFIX

ENV = "PongNoFrameskip-v4"
#: Env steps between checkpoints, by algorithm (about every 10 minutes of training on 2 cores).
SAVE_EVERY = {"pqn": 500_000, "ppo": 100_000, "dqn": 50_000}
ALGOS = tuple(SAVE_EVERY)
#: The chapter's aim: a greedy score of +18 or more.
TARGET = 18.0
#: A run folder's file of each part's 15-minute load average as it stopped.
LOADS = "loads.json"


@dataclasses.dataclass(frozen=True)
class Setting:
    """Where the runs train: the benchmark's name, files and defaults.

    :param device: torch device of training and evaluation (``cuda``: GPU utilisation is sampled while training).
    :param save_every: env steps between checkpoints, by algorithm.
    """

    name: str
    results: str
    plot: str
    budget_s: float
    num_threads: int
    device: str
    save_every: dict[str, int]
    where: str


#: 2 h on this machine's CPU cores (the chapter's reader), and 10 minutes on one GPU with its CPU cores.
CPU = Setting("pong-cpu", "pong_cpu.json", "pong_cpu.png", 7200.0, 2, "cpu", SAVE_EVERY, "CPU cores")
GPU = Setting("pong-gpu", "pong_gpu.json", "pong_gpu.png", 600.0, 1, "cuda",
              {"pqn": 500_000, "ppo": 250_000, "dqn": 100_000}, "GPU")
NAME, PLOT, RESULTS = CPU.name, CPU.plot, CPU.results


def build_parser(setting: Setting = CPU) -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run pong-cpu`` (or ``pong-gpu``: other defaults)."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {setting.name}",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("-f", "--folder", type=Path, required=True, help="output folder (runs and scores; kept)")
    parser.add_argument("--algos", nargs="+", default=list(ALGOS), choices=ALGOS)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--budget-s", type=float, default=setting.budget_s,
                        help=f"training seconds per run (default {setting.budget_s:g})")
    parser.add_argument("--games", type=int, default=10, help="greedy games of the model a run ends with")
    parser.add_argument("--curve-games", type=int, default=3, help="greedy games of each earlier checkpoint")
    parser.add_argument("--num-threads", type=int, default=setting.num_threads,
                        help=f"torch threads of each run (train's flag; default {setting.num_threads})")
    parser.add_argument("--device", default=setting.device, help=f"torch device (default {setting.device})")
    parser.add_argument("--save-every", type=int, default=None,
                        help="env steps between checkpoints (default: per algorithm, "
                             + ", ".join(f"{a} {n:,}" for a, n in setting.save_every.items()) + ")")
    parser.add_argument("--params", nargs="+", default=[], metavar="KEY:VALUE", help="overrides of every zoo entry")
    parser.add_argument("--plots", type=Path, default=RESULTS_DIR, help="folder of the PNG")
    parser.add_argument("--fresh", action="store_true",
                        help="drop the published results' rows of runs this command does not train (default: kept)")
    parser.add_argument("--quick", action="store_true",
                        help="smoke run: 40 s of training, a checkpoint every 2,000 steps, 1 game each")
    return parser


def _parts(logs: Path) -> list[Path]:
    """The run dirs of one (algo, seed), in the order they ran."""
    return sorted((p.parent for p in logs.rglob("command.txt")), key=lambda d: (d.stat().st_mtime, d.name))


def _checkpoints(run_dir: Path) -> list[tuple[int, Path]]:
    """``(env steps, path)`` of a run dir's checkpoints, in step order."""
    found = []
    for path in run_dir.glob(f"{CHECKPOINT_PREFIX}_*_steps.zip"):
        steps = path.stem.removeprefix(f"{CHECKPOINT_PREFIX}_").removesuffix("_steps")
        if steps.isdigit():
            found.append((int(steps), path))
    return sorted(found)


def _timeline(parts: Sequence[Path]) -> tuple[list[dict[str, Any]], float]:
    """Every checkpoint of a run's parts (and a stopped part's final model) with the training seconds before it was
    saved: from the part's start (its run dir's ``command.txt``, so model and env setup count too) to the file's
    save, the earlier parts' seconds added; and the seconds of all parts (each up to its last saved model)."""
    points: list[dict[str, Any]] = []
    before = 0.0
    for part in parts:
        start = (part / "command.txt").stat().st_mtime
        saved = _checkpoints(part)
        points += [{"part": part.name, "steps": steps, "path": str(path),
                    "train_s": round(before + path.stat().st_mtime - start, 1)} for steps, path in saved]
        summary, model = part / "summary.json", part / f"{ENV}.zip"
        if summary.exists() and model.exists():  # the model it saved when it stopped is the part's last point
            done = json.loads(summary.read_text())
            points.append({"part": part.name, "steps": int(done["n_timesteps"]), "path": str(model),
                           "train_s": round(before + model.stat().st_mtime - start, 1), "final": True})
            before += model.stat().st_mtime - start
        else:
            before += saved[-1][1].stat().st_mtime - start if saved else 0.0
    return points, before


def gradient_passes(algo: str, config: dict[str, Any]) -> float:
    """How many times each env step's transition goes forward and backward through the network, on average, under a
    run's resolved zoo config: PQN and PPO ``n_epochs`` (every transition of a rollout, once per epoch); DQN
    ``batch_size * gradient_steps / (train_freq * n_envs)`` (SB3's defaults: 1 gradient step every 4 steps of 1 env;
    a replayed transition is sampled that often on average)."""
    if algo == "dqn":
        freq = config.get("train_freq", 4)
        steps = freq[0] if isinstance(freq, list) else freq
        return float(config.get("batch_size", 32)) * float(config.get("gradient_steps", 1)) / (
            float(steps) * float(config.get("n_envs", 1)))
    return float(config.get("n_epochs", 10 if algo == "ppo" else 2))


def _train(logs: Path, algo: str, seed: int, save_every: int, args: argparse.Namespace, env: dict[str, str]
           ) -> dict[str, float] | None:
    """Train until the run's parts have had ``args.budget_s`` seconds: a new run, or the latest save continued. On a
    GPU: its utilisation while this part trained (None otherwise, or when nothing was left to train)."""
    points, spent = _timeline(_parts(logs))
    left = args.budget_s - spent
    if left <= 1.0:
        return None
    resume: list[str] = []
    if points:  # the latest save: a stopped part's final model, else its last checkpoint
        resume = ["-i", points[-1]["path"]]
        print(f"{algo} seed {seed}: continuing from step {points[-1]['steps']:,} ({left:.0f} s left)", file=sys.stderr)
    command = [sys.executable, "-m", "sbagents.train", "--algo", algo, "--env", ENV, "-f", str(logs), "--seed",
               str(seed), "--save-freq", str(save_every), "--eval-freq", "-1", "--final-eval-episodes", "0",
               "--verbose", "0", "--num-threads", str(args.num_threads), "--device", args.device, *resume,
               *(["-params", *args.params] if args.params else [])]
    before = set(_parts(logs))
    sampler = _gpu_sampler(args.device)
    process = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        while process.poll() is None and not set(_parts(logs)) - before:  # imports and env start are not training
            time.sleep(0.5)
        started = time.monotonic()
        t0 = time.perf_counter()
        while process.poll() is None and time.monotonic() - started < left:
            time.sleep(1.0)
        t1 = time.perf_counter()
        if process.poll() is None:
            process.send_signal(signal.SIGINT)  # the run saves its model and an interrupted summary
        _, err = process.communicate(timeout=600)
    except BaseException:
        process.kill()
        raise
    finally:
        if sampler is not None:
            sampler.close()
    if process.returncode not in (0, 130, -signal.SIGINT):
        raise RuntimeError(f"{algo} seed {seed}: train failed: {err.strip()[-600:]}")
    new = sorted(set(_parts(logs)) - before)
    if new:  # how busy the machine was while this part trained: the 15-minute load average as it stopped
        _record_part(logs / LOADS, new[-1].name, load_average()[2])
    return sampler.window(t0, t1) if sampler is not None else None


def _part_records(path: Path) -> dict[str, Any]:
    """A run folder's per-part figures (``gpu.json``, ``loads.json``): part name -> value (empty before any)."""
    return json.loads(path.read_text()) if path.exists() else {}


def _record_part(path: Path, part: str, value: Any) -> dict[str, Any]:
    """Add one part's figures to a per-part file (written atomically); all of its parts' figures."""
    records = {**_part_records(path), part: value}
    atomic_write_text(path, json.dumps(records))
    return records


def _trained(logs: Path) -> list[dict[str, Any]]:
    """When each part of a run trained (its run dir's start to its last save, local time) and the 15-minute load
    average as it stopped (None: not recorded)."""
    loads = _part_records(logs / LOADS)
    spans = []
    for part in _parts(logs):
        start = (part / "command.txt").stat().st_mtime
        saves = [path for _, path in _checkpoints(part)] + [p for p in [part / f"{ENV}.zip"] if p.exists()]
        end = max((p.stat().st_mtime for p in saves), default=start)
        spans.append({"part": part.name, "start": time.strftime("%Y-%m-%d %H:%M", time.localtime(start)),
                      "end": time.strftime("%H:%M", time.localtime(end)), "load_15min": loads.get(part.name)})
    return spans


def exploration_at(algo: str, config: dict[str, Any], steps: int) -> float | None:
    """The epsilon of a run's epsilon-greedy exploration after ``steps`` env steps: SB3's linear schedule over the
    first ``exploration_fraction`` of ``n_timesteps``, with the algorithm class's defaults for the settings the
    config leaves out (None for an algorithm without one, such as PPO, or a config without ``n_timesteps``)."""
    import inspect

    from sbagents.algos import ALGOS as CLASSES

    defaults = inspect.signature(CLASSES[algo].cls).parameters
    if "exploration_fraction" not in defaults or "n_timesteps" not in config:
        return None
    start, end, fraction = (float(config.get(k, defaults[k].default)) for k in (
        "exploration_initial_eps", "exploration_final_eps", "exploration_fraction"))
    progress = steps / (float(config["n_timesteps"]) * fraction)
    return round(start + (end - start) * min(progress, 1.0), 3)


def _gpu_name() -> str:
    """The CUDA device's name (``none`` without one)."""
    import torch

    return torch.cuda.get_device_name() if torch.cuda.is_available() else "none"


def _gpu_sampler(device: str) -> Any:
    """A :class:`~benchmarks.speed.atari_gpu_parts.GpuSampler` on a CUDA device (None on others)."""
    if not device.startswith("cuda"):
        return None
    from benchmarks.speed.atari_gpu_parts import GpuSampler

    return GpuSampler()


def _score(logs: Path, algo: str, point: dict[str, Any], games: int, env: dict[str, str]) -> dict[str, float]:
    """Greedy games of one checkpoint on the plain ALE env (on the CPU): mean and std of the game scores."""
    exp_id = int(point["part"].rsplit("_", 1)[1])  # the part's run dir, <EnvId>_<k>
    out = subprocess.run([sys.executable, "-m", "sbagents.evaluate", "--algo", algo, "--env", ENV, "-f", str(logs),
                          "--exp-id", str(exp_id),
                          *([] if point.get("final") else ["--load-checkpoint", str(point["steps"])]), "-n", str(games),
                          "--seed", "0", "--json"], env=env, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise RuntimeError(f"evaluate {point['path']} failed: {out.stderr.strip()[-600:]}")
    report = json.loads(out.stdout.strip().splitlines()[-1])
    return {"score": float(report["mean_return"]), "score_std": float(report["std_return"])}


def _run(folder: Path, algo: str, seed: int, args: argparse.Namespace, env: dict[str, str]) -> dict[str, Any]:
    """One (algo, seed): trained to its budget, every checkpoint scored (scores kept in ``scores.json``)."""
    logs = folder / algo / f"seed{seed}"
    save_every = args.save_every or args.setting.save_every[algo]
    gpu = _train(logs, algo, seed, save_every, args, env)
    gpu_path = logs / "gpu.json"  # each part's GPU figures (a continued run adds its part's)
    parts_gpu = _part_records(gpu_path) if gpu is None else _record_part(gpu_path, _parts(logs)[-1].name, gpu)
    cache_path = logs / "scores.json"
    cache = json.loads(cache_path.read_text()) if cache_path.exists() else {}
    curve = []
    points = _timeline(_parts(logs))[0]
    for i, point in enumerate(points):
        games = args.games if i == len(points) - 1 else args.curve_games  # the model the run ends with: --games
        key = f"{point['part']}:{point['steps']}" + (":final" if point.get("final") else "") + f":{games}"
        if key not in cache:
            cache[key] = {**_score(logs, algo, point, games, env), "games": games}
            atomic_write_text(cache_path, json.dumps(cache))
        curve.append({"steps": point["steps"], "train_s": point["train_s"], **cache[key]})
    within = [c for c in curve if c["train_s"] <= args.budget_s + 60]  # the last save may land just past the budget
    configs = sorted(logs.rglob("config.yml"))
    config = yaml.safe_load(configs[0].read_text()) if configs else {}
    best = max(within, key=lambda c: c["score"]) if within else None
    reached = next((c for c in within if c["score"] >= TARGET), None)
    return {"algo": algo, "seed": seed, "budget_s": args.budget_s, "games": args.games,
            "curve_games": args.curve_games, "num_threads": args.num_threads, "save_every": save_every,
            "n_envs": int(config.get("n_envs", 1)), "gradient_passes": gradient_passes(algo, config),
            "n_timesteps": int(float(config["n_timesteps"])) if "n_timesteps" in config else None,
            "exploration_end": exploration_at(algo, config, within[-1]["steps"]) if within else None,
            "device": args.device, "gpu": parts_gpu or None,
            "parts": len(_parts(logs)), "trained": _trained(logs), "curve": curve,
            "final": within[-1] if within else None, "best": best, "first_target": reached,
            "steps_per_s": round(within[-1]["steps"] / within[-1]["train_s"], 1) if within else None}


def run(argv: Sequence[str], setting: Setting = CPU) -> dict[str, Any]:
    """Every (algo, seed) run's curve and final score."""
    args = build_parser(setting).parse_args(list(argv))
    args.setting = setting
    if args.quick:
        args.budget_s, args.save_every, args.games, args.curve_games = 40.0, 2000, 1, 1
        args.seeds = args.seeds[:1]
        args.params = [*args.params, "n_envs:4"]
        args.plots = Path(tempfile.mkdtemp(prefix=f"{setting.name}-"))
    folder = args.folder.resolve()
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    load_before = load_average()
    rows = [_run(folder, algo, seed, args, env) for algo in args.algos for seed in args.seeds]
    trained = {(r["algo"], r["seed"]) for r in rows}
    kept, earlier = ([], []) if args.quick or args.fresh else \
        kept_rows(RESULTS_DIR / setting.results, trained, lambda r: (r["algo"], r["seed"]))
    rows += kept
    rows.sort(key=lambda r: (ALGOS.index(r["algo"]), r["seed"]))
    command = (f"python -m benchmarks run {setting.name} -f <output dir> --algos {' '.join(args.algos)} --seeds "
               f"{' '.join(map(str, args.seeds))} --budget-s {args.budget_s:g} --games {args.games} "
               f"--curve-games {args.curve_games} --num-threads {args.num_threads}"
               + (f" --device {args.device}" if args.device != setting.device else "")
               + (f" --params {' '.join(args.params)}" if args.params and not args.quick else ""))
    stats = {a: seed_stats([r["final"]["score"] for r in rows if r["algo"] == a and r["final"]])
             for a in ALGOS if any(r["algo"] == a and r["final"] for r in rows)}
    results = {"command": command, "earlier_commands": earlier, "env": ENV, "rows": rows, "stats": stats,
               "where": setting.where, "plot": setting.plot,
               "machine": {**machine_info(), "load_before": load_before, "load_after": load_average(),
                           **({"gpu": _gpu_name()} if args.device.startswith("cuda") else {})}}
    _plot(rows, args.plots / setting.plot, setting.where)
    return results


def run_gpu(argv: Sequence[str]) -> dict[str, Any]:
    """``pong-gpu``: :func:`run` with the GPU setting's defaults."""
    return run(argv, GPU)


def _plot(rows: list[dict[str, Any]], path: Path, where: str) -> None:
    """Greedy score against training minutes, one line per run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4))
    colours = {"pqn": "tab:blue", "dqn": "tab:orange", "ppo": "tab:green"}
    for row in rows:
        if row["curve"]:
            ax.plot([c["train_s"] / 60 for c in row["curve"]], [c["score"] for c in row["curve"]], marker=".",
                    color=colours[row["algo"]], label=f"{row['algo']} seed {row['seed']}")
    ax.axhline(TARGET, color="black", ls="--", lw=0.8)
    ax.set(xlabel="training minutes", ylabel="greedy score (games)", ylim=(-21.5, 21.5),
           title=f"{ENV} on this machine's {where}")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def render(results: dict[str, Any]) -> str:
    """The section: one row per run (final and best checkpoint), the plot."""
    m = results["machine"]
    where = results.get("where", CPU.where)
    gpu = any(r.get("gpu") for r in results["rows"])
    title = f"{m['cores']} CPU cores" if where == CPU.where else f"one GPU ({m.get('gpu', '?')}) and {m['cores']} cores"
    lines = [
        f"## Pong on {title}: PQN, DQN and PPO for the same training time", "",
        f"Command: `{results['command']}`" + "".join(f", after `{c}`" for c in reversed(results["earlier_commands"]))
        + ". Each run trains alone on the machine with its shipped zoo entry (EnvPool stepping the envs; torch "
        f"threads: {', '.join(sorted({str(r.get('num_threads', 1)) for r in results['rows']}))}) until its "
        "training has had the budget, saving a checkpoint every N env steps; then the model it ends with plays "
        "the final score's games and every earlier checkpoint fewer (the curve), greedy, on the plain ALE env. "
        "Gradient passes per env step: how often a transition goes forward and backward through the network "
        f"(PQN and PPO: epochs; DQN: batch size / train frequency). {m['cpu']}; the last command ran {m['date']}, "
        f"load {m['load_before'][0]} before / {m['load_after'][0]} after it; when each run trained is below "
        "the table.", "",
        "| algo | seed | budget s | envs | gradient passes per env step | env steps at the end | train s | env steps/s "
        f"| final score | best checkpoint (steps, score) | first save >= +{TARGET:.0f} (train min, steps) | parts |"
        + (" GPU busy % (mean, max) |" if gpu else ""),
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---|---:|" + ("---|" if gpu else ""),
    ]
    for r in results["rows"]:
        final, best = r["final"], r["best"]
        if final is None:
            lines.append(f"| {r['algo']} | {r['seed']} | {r['budget_s']:.0f} |" + " - |" * 8 + f" {r['parts']} |"
                         + (" - |" if gpu else ""))
            continue
        lines.append(f"| {r['algo']} | {r['seed']} | {r['budget_s']:.0f} | {r['n_envs']} | {r['gradient_passes']:g} | "
                     f"{final['steps']:,} | {final['train_s']:.0f}"
                     f" | {r['steps_per_s']:,.0f} | {final['score']:+.1f} +- {final['score_std']:.1f} "
                     f"({final['games']} games) | {best['steps']:,}, {best['score']:+.1f} | {_reached(r)} | "
                     f"{r['parts']} |"
                     + (f" {_gpu_cell(r.get('gpu'))} |" if gpu else ""))
    missing = [a for a in ALGOS if not any(r["algo"] == a for r in results["rows"])]
    lines += ["", *stats_bullets(results["stats"], "final score", ".1f"),
              *[f"- {r['algo']} seed {r['seed']} trained " + "; ".join(_span(t) for t in r["trained"]) + "."
                for r in results["rows"] if r.get("trained")],
              *[f"- {r['algo']} seed {r['seed']} ended at {r['final']['steps'] / r['n_timesteps']:.0%} of its entry's "
                f"n_timesteps ({r['n_timesteps']:,}): its schedules (exploration, learning-rate decay) are set for "
                "those steps, not for the budget, and got that far"
                + (f" (exploration rate at the end: {r['exploration_end']:g})."
                   if r.get("exploration_end") is not None else ".")
                for r in results["rows"] if r.get("n_timesteps") and r["final"]],
              *([f"- Not run yet: {', '.join(missing)}."] if missing else []), "",
              f"![Pong score against training time](benchmarks/results/{results.get('plot', CPU.plot)})"]
    return "\n".join(lines)


def _reached(row: dict[str, Any]) -> str:
    """When a run's saves first scored the target: training minutes and env steps (``not within the budget``)."""
    point = row.get("first_target")
    return "not within the budget" if point is None else f"{point['train_s'] / 60:.0f}, {point['steps']:,}"


def _span(part: dict[str, Any]) -> str:
    """One part's training time and load: ``2026-12-07 20:21-22:21 (15-min load 2.1 at its end)``."""
    load = part.get("load_15min")
    return f"{part['start']}-{part['end']}" + (f" (15-minute load {load:g} as it stopped)" if load is not None else "")


def _gpu_cell(parts: dict[str, dict[str, float] | None] | None) -> str:
    """Each part's GPU utilisation while it trained: ``mean, max`` per part (``-``: no samples)."""
    cells = [f"{w['util_mean']:.0f}, {w['util_max']:.0f}" if w else "-" for w in (parts or {}).values()]
    return "; ".join(cells) or "-"


BENCHMARKS = (
    Benchmark(name=CPU.name, kind="learning", results=CPU.results,
              summary="Pong on this machine's CPU cores: PQN vs SB3 DQN and PPO, greedy score against training time",
              run=run, render=render),
    Benchmark(name=GPU.name, kind="learning", results=GPU.results,
              summary="Pong on one GPU (CUDA) for 10 minutes: pong-cpu's runs with --device cuda, GPU busy sampled",
              run=run_gpu, render=render, pending=True),
)
