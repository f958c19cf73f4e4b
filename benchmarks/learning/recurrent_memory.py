"""Memory where the observation hides the state: RecurrentPPO (``ppo_lstm``) beside PPO at the same budget.

Each task trains ``ppo_lstm`` and ``ppo`` with the hyperparameters of ``zoo_configs/`` (for CartPoleNoVel: RL Zoo's
``ppo_lstm`` entry, and the same without the LSTM) over seeds, each run in its own ``python -m sbagents.train``
process (two at a time), then evaluates the final and the best model with ``python -m sbagents.evaluate -n 20``
(deterministic, the state carried through each episode). Finished runs are appended to ``--work DIR/runs.jsonl``
as they end, so a stopped measurement resumes with the same ``--work``.

    python -m benchmarks run recurrent-memory [--seeds 0 1 2] [--work DIR] [--jobs 2]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.report import load_average, machine_info
from benchmarks.stats import IQM_NOTE, format_iqm, format_mean_std, seed_stats

NAME = "recurrent-memory"
#: (env id, the level RL Zoo's ppo_lstm reaches there, what the observation hides)
TASKS: tuple[tuple[str, float | None, str], ...] = (
    ("sbagents/CartPoleNoVel-v1", 450.0, "cart and pole velocities (always 0)"),
    ("sbagents/SmartHomePrefOnce-v0", None, "the preferences after the reset"),
)
ALGOS: tuple[str, ...] = ("ppo_lstm", "ppo")
EVAL_EPISODES = 20


def build_parser() -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run recurrent-memory``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME}", description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="training seeds")
    parser.add_argument("--envs", nargs="+", default=[t[0] for t in TASKS], help="env ids (of TASKS)")
    parser.add_argument("--work", default=None, help="folder of the runs and runs.jsonl (default: a new temp dir)")
    parser.add_argument("--jobs", type=int, default=2, help="runs at a time (one core each)")
    parser.add_argument("--n-timesteps", type=int, default=None, help="override the configs' budget (smoke runs)")
    parser.add_argument("--quick", action="store_true", help="smoke run: 2,048 steps, one seed")
    return parser


def _one(algo: str, env: str, seed: int, work: Path, n_timesteps: int | None) -> dict[str, Any]:
    """Train then evaluate one (algo, env, seed) in child processes; its row."""
    folder = work / f"{algo}_{env.replace('/', '_')}_{seed}"
    budget = ["--n-timesteps", str(n_timesteps)] if n_timesteps else []
    child_env = {**os.environ, "OMP_NUM_THREADS": "1"}
    subprocess.run([sys.executable, "-m", "sbagents.train", "--algo", algo, "--env", env, "--seed", str(seed),
                    "-f", str(folder), "--final-eval-episodes", "0", *budget],
                   check=True, capture_output=True, env=child_env)
    (summary_file,) = folder.rglob("summary.json")
    summary = json.loads(summary_file.read_text())
    evaluation = _evaluate(algo, env, folder)
    best = _evaluate(algo, env, folder, "--load-best")
    return {"algo": algo, "env": env, "seed": seed, "n_timesteps": summary["n_timesteps"],
            "train_seconds": summary["train_seconds"], "return": evaluation["mean_return"],
            "return_std": evaluation["std_return"], "episodes": evaluation["n_episodes"],
            "criterion_share": evaluation.get("metrics", {}).get("criterion_share"),
            "best_return": best["mean_return"], "best_return_std": best["std_return"]}


def _evaluate(algo: str, env: str, folder: Path, *extra: str) -> dict[str, Any]:
    """``python -m sbagents.evaluate -n 20 --json`` of the run in ``folder`` (``--load-best``: the model the
    periodic evaluation kept)."""
    out = subprocess.run([sys.executable, "-m", "sbagents.evaluate", "--algo", algo, "--env", env, "-f", str(folder),
                          "-n", str(EVAL_EPISODES), "--seed", "1000", "--json", *extra],
                         check=True, capture_output=True, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    result: dict[str, Any] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Every (env, algo, seed) run, resumed from ``--work``; rows and per-(env, algo) statistics."""
    args = build_parser().parse_args(list(argv))
    if args.quick:
        args.seeds, args.n_timesteps = args.seeds[:1], args.n_timesteps or 2048
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="recurrent-memory-"))
    work.mkdir(parents=True, exist_ok=True)
    log = work / "runs.jsonl"
    done = [json.loads(line) for line in log.read_text().splitlines() if line.strip()] if log.exists() else []
    have = {(r["algo"], r["env"], r["seed"]) for r in done}
    todo = [(a, e, s) for e in args.envs for a in ALGOS for s in args.seeds if (a, e, s) not in have]
    load_before = load_average()
    print(f"{len(done)} runs done in {work}, {len(todo)} to go", file=sys.stderr)

    def job(key: tuple[str, str, int]) -> dict[str, Any]:
        row = _one(*key, work, args.n_timesteps)
        with log.open("a") as fh:  # one line per finished run: what a resumed measurement skips
            fh.write(json.dumps(row) + "\n")
        print(f"{row['algo']} {row['env']} seed {row['seed']}: return {row['return']:.1f} "
              f"({row['train_seconds']:.0f} s)", file=sys.stderr)
        return row

    for row in done:  # rows of an earlier version of this benchmark: the best model's evaluation added
        if "best_return" not in row:
            folder = work / f"{row['algo']}_{row['env'].replace('/', '_')}_{row['seed']}"
            best = _evaluate(row["algo"], row["env"], folder, "--load-best")
            row.update(best_return=best["mean_return"], best_return_std=best["std_return"])
    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        rows = done + list(pool.map(job, todo))
    wanted = {(a, e, s) for e in args.envs for a in ALGOS for s in args.seeds}
    rows = sorted((r for r in rows if (r["algo"], r["env"], r["seed"]) in wanted),
                  key=lambda r: (r["env"], ALGOS.index(r["algo"]), r["seed"]))
    stats = {f"{e} {a}": seed_stats([r["return"] for r in rows if r["env"] == e and r["algo"] == a])
             for e in args.envs for a in ALGOS}
    best_stats = {f"{e} {a}": seed_stats([r["best_return"] for r in rows if r["env"] == e and r["algo"] == a])
                  for e in args.envs for a in ALGOS}
    seeds = " ".join(str(s) for s in args.seeds)
    return {"command": f"python -m benchmarks run {NAME} --seeds {seeds} --jobs {args.jobs}",
            "machine": {**machine_info(), "load_before": load_before, "load_after": load_average()},
            "runs": rows, "stats": stats, "best_stats": best_stats}


def render(results: dict[str, Any]) -> str:
    """The section: one row per run, then per (env, algo) mean +- std and IQM of the evaluation return."""
    m, runs, stats, best_stats = results["machine"], results["runs"], results["stats"], results["best_stats"]
    levels = {env: (level, hidden) for env, level, hidden in TASKS}
    lines = [
        "## Memory: RecurrentPPO (`ppo_lstm`) beside PPO where the observation hides the state",
        "",
        f"Command: `{results['command']}`. Each run is `python -m sbagents.train --algo ALGO --env ENV --seed SEED` "
        "with `zoo_configs/` (CartPoleNoVel: RL Zoo's `ppo_lstm` entry as it is, and for `ppo` the same entry "
        "without the LSTM; SmartHomePrefOnce: SmartHome's PPO entry with `clip_obs: 100`, and the same with a "
        "64-unit LSTM; the same budget and hyperparameters on both sides), then `python -m sbagents.evaluate -n "
        f"{EVAL_EPISODES}` (deterministic, the LSTM state carried through each episode) of the final model and of "
        "the best model the periodic evaluation kept (`--load-best`, with the normalization statistics of its "
        f"moment; 5 episodes every 10,000 steps). {m['cpu']}, "
        f"{m['cores']} cores, {m['date']}, load {m['load_before'][0]} before / {m['load_after'][0]} after.",
        "",
        "| env | hidden | algo | seed | steps | return (20 ep) | best model's return | comfort share | train s |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    lines += [f"| {r['env']} | {levels.get(r['env'], (0, '?'))[1]} | {r['algo']} | {r['seed']} | "
              f"{r['n_timesteps']:,} | {r['return']:.1f} +- {r['return_std']:.1f} | "
              f"{r['best_return']:.1f} +- {r['best_return_std']:.1f} | "
              f"{'' if r.get('criterion_share') is None else format(r['criterion_share'], '.3f')} | "
              f"{r['train_seconds']:.0f} |" for r in runs]
    lines.append("")
    for key, st in stats.items():
        env, algo = key.rsplit(" ", 1)
        level = levels.get(env, (None, ""))[0]
        line = f"- {env} `{algo}`: return {format_mean_std(st, '.1f')} (mean +- std over {st['n']} seeds), " \
               f"IQM {format_iqm(st, '.1f')}"
        best = best_stats[key]
        line += f"; best model {format_mean_std(best, '.1f')}, IQM {format_iqm(best, '.1f')}"
        if level is not None:
            mine = [r for r in runs if r["env"] == env and r["algo"] == algo]
            reached = sum(r["return"] >= level for r in mine)
            reached_best = sum(r["best_return"] >= level for r in mine)
            line += (f"; at RL Zoo's level (>= {level:.0f}): final model {reached}/{st['n']} seeds, best model "
                     f"{reached_best}/{st['n']}")
        lines.append(line + ".")
    lines += ["", IQM_NOTE]
    return "\n".join(lines)


BENCHMARKS = (
    Benchmark(name=NAME, kind="learning", results="recurrent_memory.json",
              summary="ppo_lstm vs ppo at the same budget on partially observable envs (CartPoleNoVel), over seeds",
              run=run, render=render),
)
