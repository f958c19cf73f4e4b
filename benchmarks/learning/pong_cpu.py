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
"""

from __future__ import annotations

import argparse
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

from benchmarks.harness import Benchmark
from benchmarks.report import RESULTS_DIR, kept_rows, load_average, machine_info, save_figure
from benchmarks.stats import seed_stats, stats_bullets
from sbagents.core.run_dir import CHECKPOINT_PREFIX

NAME = "pong-cpu"
ENV = "PongNoFrameskip-v4"
PLOT = "pong_cpu.png"
RESULTS = "pong_cpu.json"
#: Env steps between checkpoints, by algorithm (about every 10 minutes of training here).
SAVE_EVERY = {"pqn": 500_000, "ppo": 100_000, "dqn": 50_000}
ALGOS = tuple(SAVE_EVERY)


def build_parser() -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run pong-cpu``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME}", description=__doc__.splitlines()[0])
    parser.add_argument("-f", "--folder", type=Path, required=True, help="output folder (runs and scores; kept)")
    parser.add_argument("--algos", nargs="+", default=list(ALGOS), choices=ALGOS)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--budget-s", type=float, default=7200.0, help="training seconds per run (default 2 h)")
    parser.add_argument("--games", type=int, default=10, help="greedy games of the model a run ends with")
    parser.add_argument("--curve-games", type=int, default=3, help="greedy games of each earlier checkpoint")
    parser.add_argument("--num-threads", type=int, default=2, help="torch threads of each run (train's flag)")
    parser.add_argument("--save-every", type=int, default=None,
                        help="env steps between checkpoints (default: per algorithm, "
                             + ", ".join(f"{a} {n:,}" for a, n in SAVE_EVERY.items()) + ")")
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


def _train(logs: Path, algo: str, seed: int, budget_s: float, save_every: int, params: Sequence[str],
           threads: int, env: dict[str, str]) -> None:
    """Train until the run's parts have had ``budget_s`` seconds: a new run, or the latest checkpoint continued."""
    points, spent = _timeline(_parts(logs))
    left = budget_s - spent
    if left <= 1.0:
        return
    resume: list[str] = []
    if points:  # the latest save: a stopped part's final model, else its last checkpoint
        resume = ["-i", points[-1]["path"]]
        print(f"{algo} seed {seed}: continuing from step {points[-1]['steps']:,} ({left:.0f} s left)", file=sys.stderr)
    command = [sys.executable, "-m", "sbagents.train", "--algo", algo, "--env", ENV, "-f", str(logs), "--seed",
               str(seed), "--save-freq", str(save_every), "--eval-freq", "-1", "--final-eval-episodes", "0",
               "--verbose", "0", "--num-threads", str(threads), *resume, *(["-params", *params] if params else [])]
    before = set(_parts(logs))
    process = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        while process.poll() is None and not set(_parts(logs)) - before:  # imports and env start are not training
            time.sleep(0.5)
        started = time.monotonic()
        while process.poll() is None and time.monotonic() - started < left:
            time.sleep(1.0)
        if process.poll() is None:
            process.send_signal(signal.SIGINT)  # the run saves its model and an interrupted summary
        _, err = process.communicate(timeout=600)
    except BaseException:
        process.kill()
        raise
    if process.returncode not in (0, 130, -signal.SIGINT):
        raise RuntimeError(f"{algo} seed {seed}: train failed: {err.strip()[-600:]}")


def _score(logs: Path, algo: str, point: dict[str, Any], games: int, env: dict[str, str]) -> dict[str, float]:
    """Greedy games of one checkpoint on the plain ALE env: mean and std of the game scores."""
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
    save_every = args.save_every or SAVE_EVERY[algo]
    _train(logs, algo, seed, args.budget_s, save_every, args.params, args.num_threads, env)
    cache_path = logs / "scores.json"
    cache = json.loads(cache_path.read_text()) if cache_path.exists() else {}
    curve = []
    points = _timeline(_parts(logs))[0]
    for i, point in enumerate(points):
        games = args.games if i == len(points) - 1 else args.curve_games  # the model the run ends with: --games
        key = f"{point['part']}:{point['steps']}" + (":final" if point.get("final") else "") + f":{games}"
        if key not in cache:
            cache[key] = {**_score(logs, algo, point, games, env), "games": games}
            tmp = cache_path.with_suffix(".tmp")
            tmp.write_text(json.dumps(cache))
            os.replace(tmp, cache_path)
        curve.append({"steps": point["steps"], "train_s": point["train_s"], **cache[key]})
    within = [c for c in curve if c["train_s"] <= args.budget_s + 60]  # the last save may land just past the budget
    best = max(within, key=lambda c: c["score"]) if within else None
    return {"algo": algo, "seed": seed, "budget_s": args.budget_s, "games": args.games,
            "curve_games": args.curve_games, "num_threads": args.num_threads, "save_every": save_every,
            "parts": len(_parts(logs)), "curve": curve, "final": within[-1] if within else None, "best": best,
            "steps_per_s": round(within[-1]["steps"] / within[-1]["train_s"], 1) if within else None}


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Every (algo, seed) run's curve and final score."""
    args = build_parser().parse_args(list(argv))
    if args.quick:
        args.budget_s, args.save_every, args.games, args.curve_games = 40.0, 2000, 1, 1
        args.seeds = args.seeds[:1]
        args.params = [*args.params, "n_envs:4"]
        args.plots = Path(tempfile.mkdtemp(prefix=f"{NAME}-"))
    folder = args.folder.resolve()
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    load_before = load_average()
    rows = [_run(folder, algo, seed, args, env) for algo in args.algos for seed in args.seeds]
    kept, earlier = ([], []) if args.quick or args.fresh else \
        kept_rows(RESULTS_DIR / RESULTS, {(r["algo"], r["seed"]) for r in rows}, lambda r: (r["algo"], r["seed"]))
    rows += kept
    rows.sort(key=lambda r: (ALGOS.index(r["algo"]), r["seed"]))
    command = (f"python -m benchmarks run {NAME} -f <output dir> --algos {' '.join(args.algos)} --seeds "
               f"{' '.join(map(str, args.seeds))} --budget-s {args.budget_s:g} --games {args.games} "
               f"--curve-games {args.curve_games} --num-threads {args.num_threads}"
               + (f" --params {' '.join(args.params)}" if args.params and not args.quick else ""))
    stats = {a: seed_stats([r["final"]["score"] for r in rows if r["algo"] == a and r["final"]])
             for a in ALGOS if any(r["algo"] == a and r["final"] for r in rows)}
    results = {"command": command, "earlier_commands": earlier, "env": ENV, "rows": rows, "stats": stats,
               "machine": {**machine_info(), "load_before": load_before, "load_after": load_average()}}
    _plot(rows, args.plots / PLOT)
    return results


def _plot(rows: list[dict[str, Any]], path: Path) -> None:
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
    ax.axhline(18, color="black", ls="--", lw=0.8)
    ax.set(xlabel="training minutes", ylabel="greedy score (games)", ylim=(-21.5, 21.5),
           title=f"{ENV} on this machine's CPU cores")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def render(results: dict[str, Any]) -> str:
    """The section: one row per run (final and best checkpoint), the plot."""
    m = results["machine"]
    lines = [
        f"## Pong on {m['cores']} CPU cores: PQN, DQN and PPO for the same training time", "",
        f"Command: `{results['command']}`" + "".join(f", after `{c}`" for c in reversed(results["earlier_commands"]))
        + ". Each run trains alone on the machine with its shipped zoo entry (EnvPool stepping the envs) until its "
        "training has had the budget, saving a checkpoint every N env steps; every checkpoint then plays greedy "
        f"games on the plain ALE env. {m['cpu']}, {m['date']}, load {m['load_before'][0]} before / "
        f"{m['load_after'][0]} after the last command.", "",
        "| algo | seed | budget s | env steps at the last checkpoint | train s | env steps/s | final score | best "
        "checkpoint (steps, score) | parts |",
        "|---|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    for r in results["rows"]:
        final, best = r["final"], r["best"]
        if final is None:
            lines.append(f"| {r['algo']} | {r['seed']} | {r['budget_s']:.0f} | - | - | - | - | - | {r['parts']} |")
            continue
        lines.append(f"| {r['algo']} | {r['seed']} | {r['budget_s']:.0f} | {final['steps']:,} | {final['train_s']:.0f}"
                     f" | {r['steps_per_s']:,.0f} | {final['score']:+.1f} +- {final['score_std']:.1f} "
                     f"({final['games']} games) | {best['steps']:,}, {best['score']:+.1f} | {r['parts']} |")
    lines += ["", *stats_bullets(results["stats"], "final score", ".1f"), "",
              f"![Pong score against training time](benchmarks/results/{PLOT})"]
    return "\n".join(lines)


BENCHMARKS = (
    Benchmark(name=NAME, kind="learning", results=RESULTS,
              summary="Pong on this machine's CPU cores: PQN vs SB3 DQN and PPO, greedy score against training time",
              run=run, render=render, pending=True),
)
