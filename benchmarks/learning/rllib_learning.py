"""Learning benchmarks of the Ray RLlib backend (needs ``pip install 'sbagents[distributed]'``): TreasureHunt,
``mpe2.simple_spread_v3``, and the Gymnasium envs GridWorld and SmartHome, one benchmark each.

Per seed: :func:`sbagents.rllib.training.train_rllib` with the shipped ``zoo_configs/rllib_ppo.yml`` entry
(parameter-shared PPO for teams; ``--params`` overrides it), on a local Ray instance with ``--num-env-runners``
samplers (or sampling in the driver, as the Gymnasium entries do), then the greedy team (or agent) on ``--n-eval``
seeded episodes (eval seed ``10000 + seed``, or ``--eval-seed``) from the saved
checkpoint, without Ray. Reports team return, the env's declared metrics (treasures per episode), wall-clock training
time (Ray start and algorithm build excluded, as ``summary.json``'s ``train_seconds``) and the learning curve of
``progress.csv``. For envs with a time target (:data:`CHECKPOINTS`, or ``--save-freq``/``--checkpoint-seconds``) the
run also saves module checkpoints every N env steps, and the last one saved within the target's seconds of training
(``train_seconds`` of its ``progress.csv`` row) is evaluated the same way::

    python -m benchmarks run rllib-treasure_hunt_v0 --seeds 0 1 2
    python -m benchmarks run rllib-simple_spread_v3 --seeds 0 1 2 --n-eval 300 --eval-seed 10000
    python -m benchmarks run --output '' --results SCRATCH.json rllib-treasure_hunt_v0 --seeds 0 -n 40000

Ray is imported only by the run (so ``list`` and ``render`` work without it). SIGTERM acts like Ctrl-C: the run
keeps its checkpoint, no further seed starts and nothing is saved.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shlex
import signal
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from types import FrameType
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.learning.seed_table import StatRow, iqm_note, metric_stats, stats_table
from benchmarks.report import machine_info, recorded_argv
from sbagents.core.run_dir import env_stem

#: Env -> (save every N env steps, evaluate the last checkpoint saved within this many seconds of training).
CHECKPOINTS: dict[str, tuple[int, float]] = {"mpe2.simple_spread_v3": (16_000, 300.0)}
#: Env -> (an evaluation metric the table shows, its label); TreasureHunt's treasures have a field of their own.
METRICS: dict[str, tuple[str, str]] = {"sbagents/SmartHome-v0": ("criterion_share", "comfort criterion share"),
                                       "sbagents/GridWorld-v0": ("success_rate", "success rate")}


def run_seed(
    seed: int, params: dict[str, Any], log_folder: str, n_timesteps: int | None, num_env_runners: int | None,
    num_threads: int, n_eval: int, env: str, eval_seed: int | None = None,
    checkpoints: tuple[int, float] | None = None,
) -> dict[str, Any]:
    """Train one seed and evaluate the greedy team; returns a JSON-able dict.

    :param checkpoints: (save every N env steps, seconds): also evaluate the last checkpoint saved within that much
        training (``checkpoint``: its env steps, train seconds and team return).
    """
    from sbagents.core.env_names import resolve_env
    from sbagents.core.options import EvalOptions, EvaluateOptions, ExecOptions, OutputOptions, RllibOptions, TrainSpec
    from sbagents.rllib import CHECKPOINT_DIR, PROGRESS_FILE
    from sbagents.rllib.evaluation import evaluate_checkpoint
    from sbagents.rllib.training import train_rllib

    load_start = round(os.getloadavg()[0], 2)
    start = time.perf_counter()
    save_freq = checkpoints[0] if checkpoints else -1
    result = train_rllib(TrainSpec("ppo", env, n_timesteps, params), OutputOptions(log_folder, save_freq=save_freq),
                         EvalOptions(eval_freq=-1, final_eval_episodes=0),
                         ExecOptions(seed=seed, backend="rllib", num_threads=num_threads, verbose=0),
                         RllibOptions(num_env_runners=num_env_runners))
    wall = time.perf_counter() - start
    options = EvaluateOptions(n_episodes=n_eval, seed=10_000 + seed if eval_seed is None else eval_seed)

    def evaluate(checkpoint: Path) -> dict[str, Any]:
        return evaluate_checkpoint(checkpoint, resolve_env(env), "ppo", result.experiment.env_kwargs,
                                   result.summary.get("groups"), options)

    ev = evaluate(result.run_dir / CHECKPOINT_DIR)
    with (result.run_dir / PROGRESS_FILE).open() as f:
        rows = list(csv.DictReader(f))
    s = result.summary
    extra: dict[str, Any] = {}
    if checkpoints:
        saved = [r for r in rows if r["checkpoint"] and float(r["train_seconds"]) <= checkpoints[1]]
        last = saved[-1] if saved else None
        extra["checkpoint"] = {
            "within_seconds": checkpoints[1], "env_steps": int(last["env_steps"]) if last else None,
            "train_seconds": float(last["train_seconds"]) if last else None,
            "team_return": evaluate(result.run_dir / last["checkpoint"])["mean_return"] if last else None}
    if env in METRICS:
        key, label = METRICS[env]
        extra["metric"] = {"label": label, "value": ev.get(key, ev["metrics"].get(key))}
    return {
        "seed": seed, "env": env, "treasures_per_episode": ev["metrics"].get("treasures_collected"),
        "team_return": ev["mean_return"], "std_return": ev.get("std_return"), "success_rate": ev.get("success_rate"),
        "n_eval_episodes": n_eval, "load_start": load_start,
        "load": round(os.getloadavg()[0], 2),
        "env_steps": s["n_timesteps"], "iterations": s["iterations"], "train_seconds": s["train_seconds"],
        "wall_seconds_incl_ray_start": round(wall, 1), "fps": s["fps"], "num_env_runners": s["num_env_runners"],
        "num_threads": num_threads, "policies": s["policies"], "run_dir": str(result.run_dir),
        "interrupted": result.interrupted,
        "curve": [(int(r["env_steps"]), r["episode_return_mean"]) for r in rows[:: max(len(rows) // 10, 1)]],
        **extra,
    }


NOTES: dict[str, str] = {
    "treasure_hunt_v0": "SB3's PPO on the same env: ~4.8 treasures per episode (BENCHMARKS.md, TreasureHunt learning).",
    "mpe2.simple_spread_v3": "Same 300 episodes as the SB3 rows of the simple_spread section: random play -77.12, "
                             "scripted -21.55, SB3's PPO -27.98 / -28.35 / -28.16 after 4M agent steps (1.33M env "
                             "steps) in 260-433 s. Targets: >= -30 within 10 minutes of training, >= -34 within 5 "
                             "(the checkpoint columns: the last checkpoint the run saved, every 16,000 env steps, "
                             "within 300 s of training, evaluated the same way). Load: the 1-minute load average at "
                             "the start / end of each run. The env runners are `sbagents.rllib.env_runner."
                             "LeanMultiAgentEnvRunner` (same episodes as RLlib's, less per-step bookkeeping). Runs "
                             "are not bitwise repeatable: seed 0 again, alone on the machine (load 1.7 / 1.6, "
                             "2026-12-02), reached -30.09 in 343 s (3,845 env steps/s), checkpoint -31.38 at 297 s. "
                             "The "
                             "previous entry (2 x 8 envs, 1.4M env steps, RLlib's own env runner) reached -27.72 / "
                             "-28.69 / -28.18 in 951-989 s at load 1.6-2.1. Before the backend kept time-limit "
                             "truncation apart from termination (`sbagents/rllib/truncation.py`), seed 0 of this "
                             "command reached -50.31 (2026-12-02).",
}


def env_name(env: str) -> str:
    """The env's name in file and section names: ``mpe2.simple_spread_v3`` -> ``simple_spread_v3``,
    ``sbagents/GridWorld-v0`` -> ``GridWorld-v0``."""
    return env_stem(env.rsplit(".", 1)[-1].rsplit("/", 1)[-1])


def build_parser(name: str, n_eval: int) -> argparse.ArgumentParser:
    """The benchmark's options (``n_eval``: the default of ``--n-eval``)."""
    p = argparse.ArgumentParser(prog=f"python -m benchmarks run {name}", description=(__doc__ or "").splitlines()[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--params", nargs="+", metavar="KEY:VALUE", help="overrides of the zoo entry")
    p.add_argument("-n", "--n-timesteps", type=int, default=None, help="env steps (default: the config's)")
    p.add_argument("--num-env-runners", type=int, default=None)
    p.add_argument("--num-threads", type=int, default=1, help="torch threads per process (<= 0: torch's default)")
    p.add_argument("--n-eval", type=int, default=n_eval, help=f"evaluation episodes (default: {n_eval})")
    p.add_argument("--eval-seed", type=int, default=None, help="first evaluation seed (default: 10000 + seed)")
    p.add_argument("--save-freq", type=int, default=None,
                   help="save a checkpoint every N env steps (default: the env's in CHECKPOINTS, else none)")
    p.add_argument("--checkpoint-seconds", type=float, default=None,
                   help="evaluate the last checkpoint saved within this much training (default: the env's)")
    p.add_argument("-f", "--log-folder", default=None, help="keep the runs here (default: a temp dir)")
    return p


def _raise_interrupt(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


@contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM raises :class:`KeyboardInterrupt` inside the block (the run then saves its checkpoint and stops)."""
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def run_values(runs: list[dict[str, Any]]) -> dict[str, list[float]]:
    """Per-seed values of the statistics table: team return, treasures, train s, the checkpoint's team return."""
    values = {"team_return": [float(r["team_return"]) for r in runs],
              "train_seconds": [float(r["train_seconds"]) for r in runs]}
    if all(r["treasures_per_episode"] is not None for r in runs):
        values["treasures_per_episode"] = [float(r["treasures_per_episode"]) for r in runs]
    if all((r.get("metric") or {}).get("value") is not None for r in runs):
        values["metric"] = [float(r["metric"]["value"]) for r in runs]
    checkpoints = [(r.get("checkpoint") or {}).get("team_return") for r in runs]
    if all(c is not None for c in checkpoints):
        values["checkpoint_team_return"] = [float(c) for c in checkpoints if c is not None]
    return values


def run_env(name: str, env: str, n_eval: int, argv: Sequence[str]) -> dict[str, Any]:
    """Train and evaluate every seed of benchmark ``name`` on ``env``; its results.

    :raises SystemExit: a run was interrupted (Ctrl-C, SIGTERM): nothing is saved.
    """
    from sbagents.core.zoo_config import parse_overrides

    args = build_parser(name, n_eval).parse_args(list(argv))
    params = parse_overrides(args.params, "--params")
    save_freq, within = CHECKPOINTS.get(env, (-1, 300.0))
    save_freq = save_freq if args.save_freq is None else args.save_freq
    within = within if args.checkpoint_seconds is None else args.checkpoint_seconds
    checkpoints = (save_freq, within) if save_freq > 0 else None
    runs = []
    with tempfile.TemporaryDirectory() as tmp, sigterm_as_interrupt():
        for seed in args.seeds:
            row = run_seed(seed, params, args.log_folder or tmp, args.n_timesteps, args.num_env_runners,
                           args.num_threads, args.n_eval, env, args.eval_seed, checkpoints)
            print(json.dumps({k: v for k, v in row.items() if k != "curve"}), flush=True)
            if row["interrupted"]:  # the run kept its checkpoint; no further seeds, no results
                raise SystemExit(f"{name}: seed {seed} interrupted; nothing saved")
            runs.append({k: v for k, v in row.items() if k != "run_dir"})
    return {"env": env, "params": params, "eval_seed": args.eval_seed,
            "command": " ".join(["python -m benchmarks run", name, *map(shlex.quote, recorded_argv(list(argv)))]),
            "machine": machine_info(), "runs": runs, "stats": metric_stats(run_values(runs))}


#: The statistics table's rows: label, key, format.
STAT_ROWS: tuple[StatRow, ...] = (("team return", "team_return", ".2f"),
                                  ("treasures/episode", "treasures_per_episode", ".2f"),
                                  ("checkpoint team return", "checkpoint_team_return", ".2f"),
                                  ("train s", "train_seconds", ".0f"))


def _run_cells(r: dict[str, Any], metric: bool, checkpoint: bool) -> list[str]:
    """One seed's table cells."""
    cells = [str(r["seed"]), f"{r['env_steps']:,}", f"{r['train_seconds']:.0f}", f"{r['fps']:,.0f}",
             f"{r['team_return']:.2f}"] + ([f"{r['treasures_per_episode']:.2f}"] if metric else [])
    if r.get("metric"):
        cells.append(f"{r['metric']['value']:.3f}")
    if checkpoint:
        c = r["checkpoint"]
        cells += ["-", "-", "-"] if c["env_steps"] is None else [
            f"{c['env_steps']:,}", f"{c['train_seconds']:.0f}", f"{c['team_return']:.2f}"]
    load = f"{r['load_start']} / {r['load']}" if "load_start" in r else str(r["load"])
    return cells + [load]


def render(result: dict[str, Any]) -> str:
    """The env's section of BENCHMARKS.md from its results."""
    env, runs = result["env"], result["runs"]
    metric = runs[0]["treasures_per_episode"] is not None
    own = (runs[0].get("metric") or {}).get("label")  # a Gymnasium env's metric (METRICS)
    ck = runs[0].get("checkpoint")
    ck_head = f"checkpoint <= {ck['within_seconds']:.0f} s: env steps | train s | team return | " if ck else ""
    runners = runs[0].get("num_env_runners", 2)
    who = "team" if runs[0].get("policies", "shared") != "shared" or not own else "agent"
    where = f"{runners} env runners" if runners else "sampling in the driver"
    lines = [f"## RLlib PPO: {env}", "",
             f"`python -m sbagents.train --backend rllib --algo ppo --env {env}` with the shipped "
             f"`zoo_configs/rllib_ppo.yml` entry ({where}, 1 torch thread per process), then the greedy {who} of "
             f"the final checkpoint on {runs[0]['n_eval_episodes']} episodes. Command: `{result['command']}`. Train "
             "seconds exclude Ray's start and the algorithm build.", "",
             f"| seed | env steps | train s | env steps/s | {'team return' if who == 'team' else 'return'} | "
             + ("treasures/episode | " if metric else "") + (f"{own} | " if own else "")
             + ck_head + "load |", "|---:|---:|---:|---:|---:|" + ("---:|" if metric else "") + ("---:|" if own else "")
             + ("---:|" * 3 if ck else "") + "---:|"]
    lines += ["| " + " | ".join(_run_cells(r, metric, bool(ck))) + " |" for r in runs]
    rows = tuple(("return" if key == "team_return" and who == "agent" else label, key, fmt)
                 for label, key, fmt in STAT_ROWS) + (((own, "metric", ".3f"),) if own else ())
    lines += ["", *stats_table(result["stats"], rows), "", iqm_note(len(runs))]
    if env in NOTES:
        lines += ["", NOTES[env]]
    return "\n".join(lines)


def _benchmark(env: str, n_eval: int, summary: str) -> Benchmark:
    name = f"rllib-{env_name(env)}"
    return Benchmark(name=name, kind="learning", results=f"rllib_{env_name(env)}.json", summary=summary,
                     run=partial(run_env, name, env, n_eval), render=render)


BENCHMARKS = (
    _benchmark("mpe2.simple_spread_v3", 300, "RLlib PPO on mpe2 simple_spread (needs Ray), 3 seeds, 300 episodes, "
               "checkpoint within 300 s"),
    _benchmark("treasure_hunt_v0", 100, "RLlib PPO on treasure_hunt_v0 (needs Ray), 3 seeds, treasures/episode"),
    _benchmark("sbagents/GridWorld-v0", 100, "RLlib PPO on GridWorld (needs Ray), 3 seeds, return and success"),
    _benchmark("sbagents/SmartHome-v0", 100, "RLlib PPO on SmartHome (needs Ray), 3 seeds, comfort criterion share"),
)
