"""Learning benchmarks: SB3 agents on the Kuka push and pick-and-place tasks next to panda-gym's, same algorithm,
hyperparameters, budget, seed and evaluation schedule, one seed per run.

Each benchmark trains its pairs with ``python -m sbagents.train`` (ours and panda-gym's env as two concurrent
subprocesses; the pairs one after the other), then reads each run dir's ``evaluations.npz`` (EvalCallback: returns
and ``is_success`` per evaluation episode) and ``summary.json`` into its results (the curves, see
:mod:`benchmarks.learning.kuka_curves`) and writes one learning-curve PNG per pair into ``benchmarks/results``:

- ``kuka-learning``: ``configs/kuka.yml``, *not* like for like: ours fixes the target at (0.5, 0.5) and jitters the
  book's stick by +-2 cm, panda-gym draws cube and goal in 0.3 m squares ("fixed target");
- ``kuka-learning-random``: like for like, ``configs/kuka_random.yml`` (our goal env in panda-gym's randomized
  workspace, a 4 cm cube, 50 steps, threshold 0.05): sparse reward + HER (``sbagents/PickAndPlaceGoal-v0`` vs
  ``PandaPush-v3``) and dense reward (``reward_type: dense`` vs ``PandaPushDense-v3``);
- ``kuka-pick-learning``: the grasping pick-and-place (``configs/kuka_pick.yml``: ``sbagents/KukaPickAndPlace-v0``
  vs ``PandaPickAndPlace-v3``, HER, 500k steps by default).

panda-gym lives in a venv that sees the system packages (sbagents included)::

    python -m venv --system-site-packages PANDA_VENV && PANDA_VENV/bin/pip install panda-gym
    python -m benchmarks run kuka-learning --panda-python PANDA_VENV/bin/python -f OUT -n 300000
    python -m benchmarks run kuka-learning-random --panda-python PANDA_VENV/bin/python -f OUT --pairs her
    python -m benchmarks run kuka-pick-learning --panda-python PANDA_VENV/bin/python -f OUT

``--report LABEL=RUN_DIR`` (repeated) makes the results from run dirs that already exist instead of training;
``--keep-stored`` keeps the stored reports (and notes) of the pairs not run. Runs checkpoint every ``--save-freq``
steps with the replay buffer; an unfinished run continues with ``python -m sbagents.train ... -i
RUN_DIR/rl_model_<steps>_steps.zip`` (same config, the remaining steps as ``-n``). Each like-for-like pair gets a
config of its own in ``OUT/<pair>/config.yml`` (the two entries of the config under the env ids trained; the dense
Kuka entry is stored under ``sbagents/PickAndPlaceGoal-v0-dense``, as one YAML file cannot hold two entries for one
id), and its runs in ``OUT/<pair>/``.
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import yaml

from benchmarks.harness import Benchmark
from benchmarks.learning.kuka_curves import (
    curve_run,
    default_blocks,
    load_curve,
    plot_curves,
    portable,
    render_blocks,
)
from benchmarks.report import RESULTS_DIR, load_results, recorded_argv
from sbagents.core.zoo_config import load_yaml

ROOT = Path(__file__).resolve().parents[1]
OURS_ENV = "sbagents/PickAndPlace-v0"
PANDA_ENV = "PandaPushDense-v3"
GOAL_ENV = "sbagents/PickAndPlaceGoal-v0"
PICK_ENV = "sbagents/KukaPickAndPlace-v0"


@dataclass(frozen=True)
class Pair:
    """One comparison: our env and panda-gym's, each trained from an entry of the config.

    :param name: short name (legend suffix; empty: none).
    :param ours_env: our env id.
    :param ours_entry: the config entry our run uses (stored under ``ours_env`` in the pair's config).
    :param panda_env: panda-gym's env id (its entry has the same name).
    :param plot: the PNG of its curves, relative to ``benchmarks/results``.
    :param own_config: whether the pair trains from a config of its own (``OUT/<pair>/config.yml``, runs in
        ``OUT/<pair>/``) rather than the benchmark's config (or :attr:`conf`) and ``OUT`` as they are.
    :param conf: a config file of ``benchmarks/configs`` this pair trains from instead of the benchmark's.
    :param panda: whether panda-gym's env trains too (False: ours alone, e.g. a training aid panda-gym lacks).
    """

    name: str
    ours_env: str
    ours_entry: str
    panda_env: str
    plot: str
    own_config: bool = True
    conf: str | None = None
    panda: bool = True


@dataclass(frozen=True)
class Task:
    """One benchmark: its section, config, pairs, default budget, note and title."""

    section: str
    conf: Path
    pairs: dict[str, Pair]
    n_timesteps: int
    note: str
    title: str


#: Markdown paragraph of the like-for-like report (what is matched, what is not).
LIKE_NOTE = (
    "Like for like (`benchmarks/configs/kuka_random.yml`): object start and goal uniform in 0.3 m squares around "
    "a point 0.6 m in front of each robot's base, a 4 cm cube, 50-step episodes, success within 0.05 m; the same "
    "algorithm, hyperparameters, budget, seed and evaluation schedule within each pair. Still different: the "
    "robot (Kuka iiwa with a pusher rod vs Panda), the control rate (24 vs 25 Hz), the cube's mass (0.02 vs "
    "1 kg), the observation, and the tool's start: ours 0.1 m above the table under a 0.1 m ceiling, panda-gym's "
    "0.2 m up without one but sagging to the table under random actions (the config says why). The fixed-target "
    "comparison (section kuka-learning) is not like for like.\n"
)
#: Markdown paragraph of the pick-and-place report.
PICK_NOTE = (
    "Like for like (`benchmarks/configs/kuka_pick.yml`): a 4 cm cube and a 3-D target (height U(0, 0.2) m, 30% on "
    "the table) in 0.3 m squares 0.6 m in front of each robot's base, 50-step episodes, success within 0.05 m, "
    "sparse reward with HER; the same algorithm, hyperparameters, budget, seed and evaluation schedule. Still "
    "different: the robot and its gripper (Kuka iiwa with a generated parallel jaw vs the Panda's hand), the cube's "
    "mass (0.1 vs 1 kg) and the observation's layout.\n"
)
FIXED_NOTE = ("Ours: `configs/kuka.yml`, target fixed at (0.5, 0.5), the book's stick jittered by +-2 cm; panda-gym "
              "draws cube and goal in 0.3 m squares. The like-for-like comparison is `python -m benchmarks run "
              "kuka-learning-random` (`configs/kuka_random.yml`).")

CONFIGS = ROOT / "configs"
TASKS: dict[str, Task] = {
    "kuka-learning": Task(
        "kuka-learning", CONFIGS / "kuka.yml",
        {"main": Pair("", OURS_ENV, OURS_ENV, PANDA_ENV, "kuka_learning.png", own_config=False)}, 300_000,
        FIXED_NOTE, "{algo}, {n} steps, seed {seed}: Kuka push (fixed target) vs panda-gym push"),
    "kuka-learning-random": Task(
        "kuka-learning-random", CONFIGS / "kuka_random.yml",
        {"her": Pair("sparse+HER", GOAL_ENV, GOAL_ENV, "PandaPush-v3", "kuka_learning_random.png"),
         "dense": Pair("dense", GOAL_ENV, GOAL_ENV + "-dense", "PandaPushDense-v3", "kuka_learning_random_dense.png")},
        300_000, LIKE_NOTE,
        "{algo}, {n} steps, seed {seed}: Kuka push vs panda-gym push, like for like (randomized workspace), {pair}"),
    "kuka-pick-learning": Task(
        "kuka-pick-learning", CONFIGS / "kuka_pick.yml",
        {"pick": Pair("", PICK_ENV, PICK_ENV, "PandaPickAndPlace-v3", "kuka_pick_learning.png"),
         "in-hand": Pair("half the training episodes in hand", PICK_ENV, PICK_ENV, "", "kuka_pick_in_hand.png",
                         own_config=False, conf="kuka_pick_in_hand.yml", panda=False)}, 500_000,
        PICK_NOTE, "{algo} + HER, {n} steps, seed {seed}: Kuka vs panda-gym pick-and-place"),
}


def _train_cmd(python: str, algo: str, env: str, args: argparse.Namespace, extra: list[str],
               conf: Path | None = None, log_folder: Path | None = None) -> list[str]:
    return [
        python, "-m", "sbagents.train", "--algo", algo, "--env", env, "-conf", str(conf or args.conf),
        "-f", str(log_folder or args.log_folder), "--seed", str(args.seed), "-n", str(args.n_timesteps),
        "--eval-freq", str(args.eval_freq), "--eval-episodes", str(args.eval_episodes),
        "--final-eval-episodes", str(args.final_eval_episodes), "--log-interval", "50", *_checkpointing(args),
        *extra,
    ]


def _checkpointing(args: argparse.Namespace) -> list[str]:
    """Checkpoints with the replay buffer, so that an unfinished run continues with ``-i`` (``--save-freq``)."""
    save_freq = getattr(args, "save_freq", 0)
    return ["--save-freq", str(save_freq), "--save-replay-buffer"] if save_freq > 0 else []


def _newest_run(log_folder: Path, algo: str, env_id: str) -> Path:
    runs = sorted((log_folder / algo).glob(env_id.replace("/", "_") + "_*"),
                  key=lambda p: int(p.name.rsplit("_", 1)[1]))
    if not runs:
        raise FileNotFoundError(f"no run dir for {algo} {env_id} in {log_folder}")
    return runs[-1]


def _train_both(args: argparse.Namespace, pair: Pair, conf: Path, log_folder: Path) -> list[tuple[str, str]]:
    """Train ours and panda-gym's env concurrently (ours alone if the pair says so); ``(label, run_dir)`` of each
    (labels end in the pair's name)."""
    log_folder.mkdir(parents=True, exist_ok=True)
    suffix = f" {pair.name}" if pair.name else ""
    jobs = {"ours": (pair.ours_env, _train_cmd(sys.executable, args.algo, pair.ours_env, args, [], conf, log_folder))}
    if pair.panda:
        jobs["panda-gym"] = (pair.panda_env, _train_cmd(args.panda_python, args.algo, pair.panda_env, args,
                                                        ["--gym-packages", "panda_gym"], conf, log_folder))
    procs = {}
    for label, (_, cmd) in jobs.items():
        log = (log_folder / f"{label}.log").open("w")
        print(f"[{label}{suffix}] {shlex.join(cmd)}  (log: {log.name})", flush=True)
        procs[label] = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT.parent)
        if args.sequential:
            procs[label].wait()
        time.sleep(2)  # distinct run dirs are guaranteed anyway; this keeps the start order readable
    codes = {label: p.wait() for label, p in procs.items()}
    print(f"exit codes{suffix}: {codes}", flush=True)
    return [(label + suffix, str(_newest_run(log_folder, args.algo, env))) for label, (env, _) in jobs.items()]


def pair_config(conf: Path, pair: Pair, path: Path) -> dict[str, Any]:
    """Write the two entries of ``pair`` from the zoo file ``conf`` to ``path``, under the env ids trained."""
    data = load_yaml(conf) or {}
    missing = [key for key in (pair.ours_entry, pair.panda_env) if key not in data]
    if missing:
        raise SystemExit(f"{conf} has no entry {missing[0]!r}")
    entries = {pair.ours_env: data[pair.ours_entry], pair.panda_env: data[pair.panda_env]}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"# {pair.name or 'the'} pair of {conf.name} (ours: entry {pair.ours_entry})\n"
                    + yaml.safe_dump(entries, sort_keys=False))
    return entries


def build_parser(section: str) -> argparse.ArgumentParser:
    """The options of one of :data:`TASKS`."""
    task = TASKS[section]
    p = argparse.ArgumentParser(prog=f"python -m benchmarks run {section}", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("-conf", "--conf", type=Path, default=task.conf)
    p.add_argument("--pairs", nargs="+", choices=sorted(task.pairs),
                   default=[key for key, pair in task.pairs.items() if pair.panda])
    p.add_argument("--algo", default="sac")
    p.add_argument("--panda-python", default=None, help="a Python that can import panda_gym (needed to train)")
    p.add_argument("-n", "--n-timesteps", type=int, default=task.n_timesteps)
    p.add_argument("--save-freq", type=int, default=50_000,
                   help="checkpoint (with the replay buffer) every N steps; an unfinished run continues with "
                        "sbagents.train -i; <= 0: none")
    p.add_argument("-f", "--log-folder", type=Path, default=None, help="where the runs go (needed to train)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--eval-freq", type=int, default=10_000)
    p.add_argument("--eval-episodes", type=int, default=20)
    p.add_argument("--final-eval-episodes", type=int, default=50)
    p.add_argument("--sequential", action="store_true", help="train the two runs one after the other")
    p.add_argument("--report", action="append", default=[], metavar="LABEL=RUN_DIR",
                   help="no training: the results of these existing run dirs (as the first of --pairs)")
    p.add_argument("--keep-stored", action="store_true",
                   help="keep the stored reports (and the section's notes) of the pairs not run")
    p.add_argument("--stored", type=Path, default=RESULTS_DIR / f"{section.replace('-', '_')}.json",
                   help="the results --keep-stored reads")
    p.add_argument("--plots", type=Path, default=RESULTS_DIR, help="folder of the PNGs")
    p.add_argument("--title", default="")
    return p


def _report_runs(items: list[str]) -> list[tuple[str, str]]:
    runs = []
    for item in items:
        label, sep, path = item.partition("=")
        if not sep:
            raise SystemExit(f"--report expects LABEL=RUN_DIR, got {item!r}")
        runs.append((label, path))
    return runs


def _recorded(section: str, argv: Sequence[str], log_folder: Path | None) -> str:
    """The command as the section shows it: machine paths written ``<output dir>`` (also inside ``--report``'s run
    dirs) and ``<panda-gym venv>``; ``--stored`` and ``--plots`` left out."""
    placeholders = {"-f": "<output dir>", "--log-folder": "<output dir>",
                    "--panda-python": "<panda-gym venv>/bin/python"}
    hidden = {"--stored", "--plots"}
    out: list[str] = []
    for i, arg in enumerate(argv):
        flag = argv[i - 1] if i else ""
        if arg not in hidden and flag not in hidden:
            out.append(portable(placeholders.get(flag, arg), log_folder))
    words = ["python", "-m", "benchmarks", "run", section, *recorded_argv(out)]
    return " ".join(w if "<" in w else shlex.quote(w) for w in words)


def measure_pair(task: Task, key: str, args: argparse.Namespace) -> dict[str, Any]:
    """Train (or, with ``--report``, read) one pair; its report, with its plot written."""
    pair = task.pairs[key]
    if args.report:
        runs = _report_runs(args.report)
    else:
        if (pair.panda and args.panda_python is None) or args.log_folder is None:
            raise SystemExit("training needs --panda-python and -f (or --report LABEL=RUN_DIR ...)")
        folder = args.log_folder / key if pair.own_config else args.log_folder
        conf = folder / "config.yml" if pair.own_config else CONFIGS / pair.conf if pair.conf else args.conf
        if pair.own_config:
            pair_config(args.conf, pair, conf)
        runs = _train_both(args, pair, conf, folder)
    curves = [load_curve(label, run_dir) for label, run_dir in runs]
    title = args.title or task.title.format(algo=args.algo.upper(), n=args.n_timesteps, seed=args.seed,
                                            pair=pair.name)
    plot_curves(curves, args.plots / pair.plot, title)
    return {"key": key, "seed": args.seed, "title": title, "n_episodes": curves[0].n_episodes,
            "runs": [curve_run(c, args.log_folder) for c in curves]}


def _merge_stored(stored: dict[str, Any], reports: list[dict[str, Any]], command: str,
                  task: Task) -> tuple[list[dict[str, Any]], list[dict[str, str]]]:
    """``--keep-stored``: the stored reports with ``reports`` in place of those of the same pairs, and the stored
    blocks (notes and tables), followed by the default blocks of a pair the stored section lacks."""
    fresh = {r["key"]: r for r in reports}
    merged = [fresh.pop(r["key"], r) for r in stored["reports"]] + list(fresh.values())
    blocks = list(stored["blocks"])
    for report in fresh.values():
        blocks += default_blocks(report, f"### {report['title']}", f"Command: `{command}`.",
                                 f"benchmarks/results/{task.pairs[report['key']].plot}")
    return merged, blocks


def run_task(section: str, argv: Sequence[str]) -> dict[str, Any]:
    """Measure the pairs asked for; the section's results (with ``--keep-stored``, beside the stored others)."""
    task = TASKS[section]
    args = build_parser(section).parse_args(list(argv))
    keys = args.pairs[:1] if args.report else args.pairs
    command = _recorded(section, argv, args.log_folder)
    reports, blocks = [], []
    for i, key in enumerate(keys):
        report = measure_pair(task, key, args)
        reports.append(report)
        heading = f"{'##' if i == 0 else '###'} {report['title']}"
        note = f"Command: `{command}`." + (f"\n\n{task.note.strip()}" if i == 0 else "")
        blocks += default_blocks(report, heading, note, f"benchmarks/results/{task.pairs[key].plot}")
    commands = [command]
    if args.keep_stored and args.stored.exists():
        stored = load_results(args.stored)
        reports, blocks = _merge_stored(stored, reports, command, task)
        commands = list(dict.fromkeys([*stored.get("commands", []), command]))
    return {"commands": commands, "seeds": sorted({r["seed"] for r in reports}), "reports": reports,
            "blocks": blocks}


def render(results: dict[str, Any]) -> str:
    """The section: its blocks (notes verbatim, tables from the reports' runs)."""
    return render_blocks(results)


BENCHMARKS = tuple(
    Benchmark(name=section, kind="learning", results=f"{section.replace('-', '_')}.json",
              summary=summary, run=partial(run_task, section), render=render)
    for section, summary in (
        ("kuka-learning", "SAC on the Kuka push (fixed target) vs panda-gym's push, 1 seed: success over training"),
        ("kuka-learning-random", "Kuka push vs panda-gym push like for like (HER and dense pairs), 1 seed"),
        ("kuka-pick-learning", "Kuka pick-and-place vs panda-gym's (SAC + HER), 1 seed: success over training"),
    )
)
