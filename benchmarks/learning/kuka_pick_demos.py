"""Chapter 5's pick-and-place learned from demonstrations: ``sbagents/KukaPickAndPlace-v0`` with SAC + HER given 100
episodes of the scripted grasp, beside behaviour cloning alone, learning without them, panda-gym's
``PandaPickAndPlace-v3`` given as many episodes of a scripted Panda grasp (``pip install panda-gym``) and chapter 6's
``RobustKukaPickAndPlace-v0``, over seeds.

Per seed: ``python -m sbagents.collect --policy scripted`` records the demonstrations (reset seeds from
``1000 * seed``); then each variant trains with ``benchmarks/configs/kuka_pick.yml`` (SAC + HER, 64-64 networks, batch
256, half a gradient step per env step, the settings of the ``kuka-pick-learning`` runs without demonstrations):

- ``demos``: ``--pretrain DATASET`` (behaviour cloning first), then ``--demos DATASET --demo-bc W`` (the
  demonstrations in the replay buffer, and the cloning loss, behind a Q-filter after ``--demo-filter-after`` steps);
- ``bc``: ``--pretrain DATASET`` alone, with no learning step (``learning_starts`` above the budget);
- ``none``: SAC + HER without demonstrations (500k steps per seed; the stored ``kuka-pick-learning`` run of seed 0
  stands for seed 0 unless ``none:0`` is trained);
- ``panda-demos``, ``panda-bc``, ``robust-demos``, ``robust-bc``: ``demos`` and ``bc`` on the Panda and on the robust
  env.

Every run ends with 50 greedy episodes (the success rate in the table); ``demos`` and ``none`` also evaluate 20
greedy episodes every 10k steps (the curves). Each run has a folder per variant, seed and budget
(``OUT/demos/seed0-n500000``). Runs that finished are kept (a ``summary.json`` in their folder): run the command again
to add seeds or variants. The published results' rows of (variant, seed) pairs a command does not train are kept
(``--fresh``: not), so seeds measured in one session and the next end up in one table. A run that learns saves a
checkpoint with its replay buffer every 50k steps; the command run again continues a run that stopped (a session
that ended) from its latest checkpoint with ``train -i`` and that buffer, without ``--pretrain``, and the table counts
the parts' training time together. ``--jobs 2`` trains two runs at once::

    python -m benchmarks run kuka-pick-demos -f OUT [--seeds 0 1 2] [--variants demos@500000 bc panda-demos:0]
        [--jobs 2]
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import tempfile
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import Benchmark
from benchmarks.report import RESULTS_DIR, kept_rows, load_average, machine_info, run_module, save_figure
from benchmarks.stats import seed_stats, stats_bullets
from sbagents.core.run_dir import CHECKPOINT_PREFIX
from sbagents.replay.buffer_files import checkpoint_steps
from sbagents.state_files import REPLAY_BUFFER_FILE, replay_buffer_steps

NAME = "kuka-pick-demos"
ENV = "sbagents/KukaPickAndPlace-v0"
PANDA = "PandaPickAndPlace-v3"
ROBUST = "sbagents/RobustKukaPickAndPlace-v0"
CONFIG = "benchmarks/configs/kuka_pick.yml"
PLOT = "kuka_pick_demos.png"
FINAL_EPISODES = 50
DEMOS = ("--pretrain", "{dataset}", "--pretrain-steps", "5000", "--demos", "{dataset}", "--demo-bc", "100",
         "--demo-filter-after", "20000")
CLONE = ("--pretrain", "{dataset}", "--pretrain-steps", "5000")


@dataclass(frozen=True)
class Variant:
    """One way to train: the env, the extra ``train`` flags (``{dataset}``: the seed's demonstrations) and the env
    steps (``bc``: no learning step within them)."""

    env: str
    flags: tuple[str, ...]
    steps: int


VARIANTS: dict[str, Variant] = {
    "demos": Variant(ENV, DEMOS, 200_000), "bc": Variant(ENV, CLONE, 100), "none": Variant(ENV, (), 500_000),
    "panda-demos": Variant(PANDA, DEMOS, 200_000), "panda-bc": Variant(PANDA, CLONE, 100),
    "robust-demos": Variant(ROBUST, DEMOS, 200_000), "robust-bc": Variant(ROBUST, CLONE, 100),
}


def build_parser() -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run kuka-pick-demos``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME}", description=__doc__.splitlines()[0])
    parser.add_argument("-f", "--folder", type=Path, required=True, help="output folder (datasets and runs; kept)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--variants", nargs="+", default=["demos", "bc"], metavar="VARIANT[:SEEDS][@STEPS]",
                        help=f"of {', '.join(VARIANTS)}; VARIANT:0,1 trains those seeds only (default: --seeds), "
                             "VARIANT@500000 that budget (default: --steps)")
    parser.add_argument("--episodes", type=int, default=100, help="demonstration episodes per seed")
    parser.add_argument("--steps", type=int, default=None,
                        help="env steps of the *demos variants without @STEPS (default 200000)")
    parser.add_argument("--jobs", type=int, default=1, help="runs trained at once")
    parser.add_argument("--save-freq", type=int, default=50_000, help="env steps between checkpoints (with the buffer)")
    parser.add_argument("--plots", type=Path, default=RESULTS_DIR, help="folder of the PNG")
    parser.add_argument("--fresh", action="store_true",
                        help="drop the published results' rows of runs this command does not train (default: kept)")
    parser.add_argument("--quick", action="store_true",
                        help="smoke run: seed 0, 5 episodes, 3000 steps (or --steps), a checkpoint every 1000")
    return parser


def _jobs(given: Sequence[str], seeds: Sequence[int], steps: dict[str, int]) -> list[tuple[str, int, int]]:
    """``VARIANT[:s1,s2][@STEPS]`` items -> (variant, seed, env steps) triples (``steps``: each variant's default)."""
    jobs = []
    for item in given:
        head, _, budget = item.partition("@")
        name, _, own = head.partition(":")
        if name not in VARIANTS:
            raise SystemExit(f"--variants: {name!r} is not one of {', '.join(VARIANTS)}")
        if budget and not budget.isdigit():
            raise SystemExit(f"--variants: {item!r}: @STEPS takes a whole number of env steps")
        n = int(budget) if budget else steps[name]
        jobs += [(name, int(s), n) for s in own.split(",")] if own else [(name, s, n) for s in seeds]
    for name in {v for v, _, _ in jobs}:
        if len({n for v, _, n in jobs if v == name}) > 1:
            raise SystemExit(f"--variants: {name} is given two budgets; one per command")
    return jobs


def _dataset(folder: Path, env_id: str, seed: int, episodes: int, env: dict[str, str]) -> str:
    """The seed's demonstrations on ``env_id`` (recorded once): our scripted grasp, or the Panda's
    (:mod:`benchmarks.learning.panda_pick`)."""
    name = env_id.split("/")[-1].lower()
    dataset = f"bench/{name}-scripted-s{seed}-e{episodes}-v0" if env_id != ENV else \
        f"bench/kuka-pick-scripted-s{seed}-e{episodes}-v0"
    if not (folder / "datasets" / dataset).exists():
        if env_id == PANDA:
            from benchmarks.learning.panda_pick import record

            os.environ["MINARI_DATASETS_PATH"] = env["MINARI_DATASETS_PATH"]
            record(dataset, episodes, 1000 * seed)
        else:
            run_module("sbagents.collect", "--env", env_id, "--policy", "scripted", "--episodes", str(episodes),
                       "--dataset", dataset, "--seed", str(1000 * seed), "--ref-episodes", "0", env=env)
    return dataset


def _parts(logs: Path) -> list[Path]:
    """The run dirs of one (variant, seed, budget), in order: the first run, then each one that continued it."""
    return sorted((p.parent for p in logs.rglob("command.txt")), key=lambda d: (d.stat().st_mtime, d.name))


def _resumed_from(run_dir: Path) -> int | None:
    """The step of the checkpoint ``run_dir``'s run continued (``-i`` in its ``command.txt``), else None."""
    words = shlex.split((run_dir / "command.txt").read_text())
    return checkpoint_steps(Path(words[words.index("-i") + 1])) if "-i" in words else None


def _resume_point(parts: Sequence[Path]) -> Path | None:
    """The latest checkpoint of an unfinished run whose replay buffer was saved with it (the run dir's buffer records
    the step it was saved at), else None."""
    for run_dir in reversed(parts):
        buffer = run_dir / REPLAY_BUFFER_FILE
        saved_at = replay_buffer_steps(buffer) if buffer.exists() else None
        checkpoint = run_dir / f"{CHECKPOINT_PREFIX}_{saved_at}_steps.zip"
        if saved_at is not None and checkpoint.exists():
            return checkpoint
    return None


def _without_pretrain(flags: Sequence[str]) -> list[str]:
    """``flags`` less ``--pretrain DATASET`` and ``--pretrain-steps N`` (a continued model keeps its weights)."""
    out, skip = [], False
    for flag in flags:
        if skip or flag in ("--pretrain", "--pretrain-steps"):
            skip = not skip
            continue
        out.append(flag)
    return out


def _train(folder: Path, variant: str, seed: int, dataset: str, steps: int, save_freq: int, env: dict[str, str]
           ) -> dict[str, Any]:
    """One run of ``steps`` env steps (kept when it finished already, continued from its latest checkpoint and replay
    buffer when it stopped before): its row with its curve."""
    spec = VARIANTS[variant]
    logs = folder / variant / f"seed{seed}-n{steps}"
    parts = _parts(logs)
    started, trained = time.time(), not (parts and (parts[-1] / "summary.json").exists())
    if trained:
        flags = [f.format(dataset=dataset) for f in spec.flags]
        point = _resume_point(parts)
        budget = steps
        if point is not None:  # -n counts the steps still to take
            flags, budget = [*_without_pretrain(flags), "-i", str(point)], steps - (checkpoint_steps(point) or 0)
            print(f"{variant} seed {seed}: continuing {point.parent.name} from step {steps - budget:,}",
                  file=sys.stderr)
        periodic = ("--eval-freq", "-1") if spec.steps <= 100 else (
            "--eval-freq", "10000", "--eval-episodes", "20", "--save-freq", str(save_freq), "--save-replay-buffer")
        packages = ("--gym-packages", "panda_gym") if spec.env == PANDA else ()
        run_module("sbagents.train", "--algo", "sac", "--env", spec.env, "-conf", CONFIG, *packages, *flags, "--seed",
                   str(seed), "-n", str(budget), "-f", str(logs), *periodic, "--final-eval-episodes",
                   str(FINAL_EPISODES), "--verbose", "0", env=env)
        parts = _parts(logs)
    summary = json.loads((parts[-1] / "summary.json").read_text())
    steps_at: list[int] = []
    success: list[float] = []
    train_s = float(summary["train_seconds"])
    starts = [_resumed_from(d) for d in parts]  # each part's checkpoint step (None: the first run)
    for i, run_dir in enumerate(parts):
        end = starts[i + 1] if i + 1 < len(parts) else None
        if end is not None:  # the time this part took to its checkpoint the next one continued
            train_s += (run_dir / f"{CHECKPOINT_PREFIX}_{end}_steps.zip").stat().st_mtime - \
                (run_dir / "command.txt").stat().st_mtime
        if (run_dir / "evaluations.npz").exists():
            with np.load(run_dir / "evaluations.npz") as curve:
                for t, s in zip(curve["timesteps"], np.asarray(curve["successes"], dtype=float).mean(axis=1),
                                strict=True):
                    if end is None or t <= end:
                        steps_at.append(int(t))
                        success.append(float(s))
    first_90 = next((t for t, s in zip(steps_at, success, strict=True) if s >= 0.9), None)
    resumed = [r for r in starts if r is not None]
    return {"variant": variant, "env": spec.env, "seed": seed,
            "n_timesteps": int(summary["n_timesteps"]),  # the model's count: a continued run's total
            "final_success": float(summary["eval"]["success_rate"]), "final_episodes": FINAL_EPISODES,
            "final_cost": summary["eval"].get("mean_cost"),
            "best_eval_success": max(success) if success else None, "first_eval_at_90": first_90,
            "train_s": round(train_s, 1), "wall_s": round(time.time() - started, 1) if trained else None,
            "resumed_from": resumed, "steps": steps_at, "success": success,
            "demos": summary.get("demos"), "pretrain": summary.get("pretrain")}


def _stored_none() -> list[dict[str, Any]]:
    """The ``kuka-pick-learning`` run of our env without demonstrations (seed 0, 500k steps), as a row."""
    path = RESULTS_DIR / "kuka_pick_learning.json"
    if not path.exists():
        return []
    for report in json.loads(path.read_text())["reports"]:
        for run in report["runs"]:
            if report["key"] == "pick" and run["label"] == "ours":
                return [{"variant": "none", "env": ENV, "seed": report["seed"], "n_timesteps": run["n_timesteps"],
                         "final_success": run["final_success"], "final_episodes": run["final_episodes"],
                         "best_eval_success": max(s for s in run["success"] if s is not None),
                         "first_eval_at_90": None, "train_s": run["train_s"], "wall_s": None,
                         "steps": run["steps"], "success": run["success"], "stored": "kuka-pick-learning"}]
    return []


def _earlier(jobs: Sequence[tuple[str, int, int]], path: Path = RESULTS_DIR / "kuka_pick_demos.json"
             ) -> tuple[list[dict[str, Any]], list[str]]:
    """The published results' rows of (variant, seed) pairs that ``jobs`` do not train (not the stored ``none`` row,
    which :func:`_stored_none` adds), and the commands that measured them."""
    return kept_rows(path, {(v, s) for v, s, _ in jobs}, lambda r: (r["variant"], r["seed"]),
                     skip=lambda r: bool(r.get("stored")))


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Every (variant, seed) run's row, then each variant's statistics over seeds."""
    args = build_parser().parse_args(list(argv))
    if args.quick:  # the plot goes to a scratch folder too
        args.seeds, args.episodes, args.steps, args.save_freq = args.seeds[:1], 5, args.steps or 3000, 1000
        args.plots = Path(tempfile.mkdtemp(prefix=f"{NAME}-"))
    folder = args.folder.resolve()
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MINARI_DATASETS_PATH": str(folder / "datasets")}
    load_before = load_average()
    defaults = {v: args.steps if args.steps and v.endswith("demos") else spec.steps for v, spec in VARIANTS.items()}
    jobs = _jobs(args.variants, args.seeds, defaults)
    steps = {v: n for v, _, n in jobs}
    datasets = {(VARIANTS[v].env, s): _dataset(folder, VARIANTS[v].env, s, args.episodes, env)
                for v, s, _ in jobs if VARIANTS[v].flags}
    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        rows = list(pool.map(lambda job: _train(folder, job[0], job[1], datasets.get((VARIANTS[job[0]].env, job[1]),
                                                                                      ""), job[2], args.save_freq,
                                                       env), jobs))
    kept, earlier = ([], []) if args.quick or args.fresh else _earlier(jobs)
    trained_none = {s for v, s, _ in jobs if v == "none"} | {r["seed"] for r in kept if r["variant"] == "none"}
    rows += kept + [r for r in _stored_none() if r["seed"] not in trained_none]  # the stored run stands for its seed
    rows.sort(key=lambda r: (list(VARIANTS).index(r["variant"]), r["seed"]))
    for row in rows:
        print(f"{row['variant']} seed {row['seed']}: final success {row['final_success']:.2f}", file=sys.stderr)
    variants = [v for v in VARIANTS if any(r["variant"] == v for r in rows)]
    stats = {v: seed_stats([r["final_success"] for r in rows if r["variant"] == v]) for v in variants}
    steps.update({r["variant"]: r["n_timesteps"] for r in kept if r["variant"] not in steps})
    results = {"command": f"python -m benchmarks run {NAME} -f <output dir> --seeds "
                          f"{' '.join(map(str, args.seeds))} --variants {' '.join(args.variants)} --episodes "
                          f"{args.episodes} --jobs {args.jobs}" + (f" --steps {args.steps}" if args.steps else ""),
               "earlier_commands": earlier, "episodes": args.episodes,
               "steps": {v: steps.get(v, VARIANTS[v].steps) for v in variants},
               "envs": {v: VARIANTS[v].env for v in variants},
               "flags": {v: " ".join(VARIANTS[v].flags) for v in variants},
               "machine": {**machine_info(), "load_before": load_before, "load_after": load_average()},
               "rows": rows, "stats": stats}
    _plot(rows, args.plots / PLOT)
    return results


def _plot(rows: list[dict[str, Any]], path: Path) -> None:
    """Success (20 greedy episodes) against env steps, one line per run with a curve."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4))
    colours = {"demos": "tab:blue", "none": "tab:grey", "bc": "tab:blue", "panda-demos": "tab:green",
               "panda-bc": "tab:green", "robust-demos": "tab:red", "robust-bc": "tab:red"}
    for row in rows:
        if row["steps"]:
            ax.plot(row["steps"], [100 * s for s in row["success"]], color=colours[row["variant"]], alpha=0.8,
                    label=f"{row['variant']} seed {row['seed']}")
        elif row["variant"].endswith("bc"):
            ax.axhline(100 * row["final_success"], color=colours[row["variant"]], ls=":", lw=1)
    ax.axhline(90, color="black", ls="--", lw=0.8)
    ax.set(xlabel="env steps", ylabel="success (%)", ylim=(-3, 103), xlim=(0, None),
           title="Pick-and-place, SAC + HER with 100 scripted demonstrations (dotted: BC alone, final)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def _jobs_given(command: str) -> str:
    """``3 at once`` from a command's ``--jobs 3`` (``1 at a time`` without it)."""
    words = command.split()
    jobs = words[words.index("--jobs") + 1] if "--jobs" in words[:-1] else "1"
    return "1 at a time" if jobs == "1" else f"{jobs} at once"


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.0f}%"


def render(results: dict[str, Any]) -> str:
    """The section: one row per run, each variant's success over seeds, the plot."""
    m = results["machine"]
    lines = [
        "## Kuka pick-and-place from demonstrations (SAC + HER, 100 scripted episodes)",
        "",
        f"Command: `{results['command']}`"
        + "".join(f", after `{c}`" for c in reversed(results.get("earlier_commands", [])))
        + (" (the rows of runs a later command did not train are kept from the earlier one)"
           if results.get("earlier_commands") else "")
        + f". Per env and seed, {results['episodes']} episodes of the env's scripted "
        "grasp (`python -m sbagents.collect --policy scripted`; for the Panda, `benchmarks/learning/panda_pick.py`, "
        "which succeeds in 100 of 100 episodes) are the demonstrations; every variant trains `sac` with "
        f"`{CONFIG}` (HER, 64-64 networks, batch 256, half a gradient step per env step: the settings of the runs "
        "without demonstrations in the pick-and-place section above) and ends with "
        f"{FINAL_EPISODES} greedy episodes (final success and mean episode cost). Flags per variant: "
        + "; ".join(f"{v} ({results.get('envs', {}).get(v, ENV)}): `{flags or '(none)'}`, "
                    f"{results['steps'][v]:,} steps" for v, flags in results["flags"].items())
        + ". The `*bc` variants take no learning step (`learning_starts` 1000 is above their budget). A run that "
        "stopped (a session's end) went on from its latest checkpoint with `train -i` and its replay buffer; its train "
        "seconds add its parts'. "
        f"{m['cpu']}, {m['cores']} cores, {m['date']}, load {m['load_before'][0]} before / {m['load_after'][0]} "
        f"after; `--jobs N` trains N runs at once ({_jobs_given(results['command'])} here).",
        "",
        "| variant | env | seed | steps | final success (50) | cost | best eval (20) | first eval >= 90% | train s |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results["rows"]:
        stored = f" (stored: {r['stored']})" if r.get("stored") else ""
        if r.get("resumed_from"):  # a run that stopped and went on from a checkpoint (train -i with its buffer)
            stored += " (continued at " + ", ".join(f"{s:,}" for s in r["resumed_from"]) + ")"
        first = "-" if r["first_eval_at_90"] is None else f"{r['first_eval_at_90']:,}"
        cost = "-" if r.get("final_cost") is None else f"{r['final_cost']:.2f}"
        lines.append(f"| {r['variant']}{stored} | {r.get('env', ENV)} | {r['seed']} | {r['n_timesteps']:,} | "
                     f"{_pct(r['final_success'])} | {cost} | {_pct(r['best_eval_success'])} | {first} | "
                     f"{r['train_s']:.0f} |")
    lines += ["", *stats_bullets(results["stats"], "final success", ".2f"), "",
              f"![success vs steps](benchmarks/results/{PLOT})"]
    return "\n".join(lines)


BENCHMARKS = (
    Benchmark(name=NAME, kind="learning", results="kuka_pick_demos.json",
              summary="Kuka pick-and-place from 100 scripted demonstrations (SAC + HER + BC) vs BC alone, over seeds",
              run=run, render=render),
)
