"""Learning benchmark: an SB3 agent on the Kuka push task next to panda-gym's push, same algo and budget.

``run`` trains both with ``python -m sbagents.train`` (same zoo file, same seed, same budget, same
evaluation schedule) as two concurrent subprocesses, then ``report`` reads each run dir's
``evaluations.npz`` (EvalCallback: returns and ``is_success`` per evaluation episode) and
``summary.json`` and writes a learning-curve PNG and a Markdown table.

panda-gym lives in a venv that sees the system packages (sbagents included)::

    python -m venv --system-site-packages PANDA_VENV && PANDA_VENV/bin/pip install panda-gym
    nohup python benchmarks/kuka_learning.py run --algo sac -n 300000 -f OUT --panda-python PANDA_VENV/bin/python \
        > OUT.log 2>&1 &
    python benchmarks/kuka_learning.py report --run ours=OUT/sac/sbagents_PickAndPlace-v0_1 \\
        --run panda=OUT/sac/PandaPushDense-v3_1

``run`` calls ``report`` itself when both trainings end. Timings depend on the machine's load.

``run``'s default config (``configs/kuka.yml``) is *not* like for like: ours fixes the target at (0.5, 0.5) and
jitters the book's stick by +-2 cm, panda-gym draws cube and goal in 0.3 m squares (published section
``kuka-learning``, "fixed target"). ``like`` is: with ``configs/kuka_random.yml`` (our goal env in panda-gym's
randomized workspace with a 4 cm cube, 50 steps, threshold 0.05) it trains two pairs with the same algorithm,
hyperparameters, budget, seed and evaluation schedule, sparse reward + HER (``sbagents/PickAndPlaceGoal-v0`` vs
``PandaPush-v3``) and dense reward (the goal env with ``reward_type: dense`` vs ``PandaPushDense-v3``), and
writes one plot with the four learning curves and one Markdown section::

    python benchmarks/kuka_learning.py like -n 300000 -f OUT --panda-python PANDA_VENV/bin/python

``pick`` does the same for the grasping pick-and-place (``configs/kuka_pick.yml``: ``sbagents/KukaPickAndPlace-v0``
vs ``PandaPickAndPlace-v3``, HER, 500k steps by default)::

    python benchmarks/kuka_learning.py pick -f OUT --panda-python PANDA_VENV/bin/python

``run``, ``like`` and ``pick`` checkpoint every ``--save-freq`` steps with the replay buffer; an unfinished run
continues with ``python -m sbagents.train ... -i RUN_DIR/rl_model_<steps>_steps.zip`` (same config, the remaining
steps as ``-n``).

Each pair gets a config of its own in ``OUT/<pair>/config.yml`` (the two entries of ``kuka_random.yml`` under
the env ids trained; the dense Kuka entry is stored under ``sbagents/PickAndPlaceGoal-v0-dense``, as one YAML
file cannot hold two entries for one id), and its runs in ``OUT/<pair>/``; the two runs of a pair train
concurrently, the pairs one after the other.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sbagents.core.zoo_config import load_yaml

ROOT = Path(__file__).resolve().parent
DEFAULT_CONF = ROOT / "configs" / "kuka.yml"
DEFAULT_OUT = ROOT / "results" / "kuka_learning"
OURS_ENV = "sbagents/PickAndPlace-v0"
PANDA_ENV = "PandaPushDense-v3"
LIKE_CONF = ROOT / "configs" / "kuka_random.yml"
LIKE_OUT = ROOT / "results" / "kuka_learning_random"
GOAL_ENV = "sbagents/PickAndPlaceGoal-v0"


@dataclass(frozen=True)
class Pair:
    """One like-for-like comparison: our env and panda-gym's, each trained from an entry of the config.

    :param name: short name (run subfolder, legend suffix).
    :param ours_env: our env id.
    :param ours_entry: the config entry our run uses (stored under ``ours_env`` in the pair's config).
    :param panda_env: panda-gym's env id (its entry has the same name).
    """

    name: str
    ours_env: str
    ours_entry: str
    panda_env: str


#: The pairs of ``like``: sparse reward + HER, and dense reward without HER.
LIKE_PAIRS: dict[str, Pair] = {
    "her": Pair("sparse+HER", GOAL_ENV, GOAL_ENV, "PandaPush-v3"),
    "dense": Pair("dense", GOAL_ENV, GOAL_ENV + "-dense", "PandaPushDense-v3"),
}
PICK_CONF = ROOT / "configs" / "kuka_pick.yml"
PICK_OUT = ROOT / "results" / "kuka_pick_learning"
PICK_ENV = "sbagents/KukaPickAndPlace-v0"
#: The pair of ``pick``: grasping pick-and-place with HER.
PICK_PAIRS: dict[str, Pair] = {"pick": Pair("pick-and-place", PICK_ENV, PICK_ENV, "PandaPickAndPlace-v3")}


@dataclass
class Curve:
    """One run's evaluation history.

    :param label: legend label.
    :param env_id: environment id.
    :param steps: ``(n_evals,)`` env steps at each evaluation.
    :param success: ``(n_evals,)`` success rate of each evaluation (NaN if the env reports none).
    :param mean_return: ``(n_evals,)`` mean evaluation return.
    :param n_episodes: evaluation episodes per point.
    :param summary: the run's ``summary.json`` (empty if missing).
    :param command: the training command (``command.txt``), if recorded.
    """

    label: str
    env_id: str
    steps: np.ndarray
    success: np.ndarray
    mean_return: np.ndarray
    n_episodes: int
    summary: dict[str, Any]
    command: str


def load_curve(label: str, run_dir: str | Path) -> Curve:
    """Read ``evaluations.npz``, ``summary.json`` and ``command.txt`` of a ``sbagents.train`` run dir."""
    run_dir = Path(run_dir)
    data = np.load(run_dir / "evaluations.npz")
    results = np.asarray(data["results"], dtype=np.float64)
    if "successes" in data and np.asarray(data["successes"]).size:
        success = np.asarray(data["successes"], dtype=np.float64).mean(axis=1)
    else:
        success = np.full(len(results), np.nan)
    summary_path, command_path = run_dir / "summary.json", run_dir / "command.txt"
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    if not summary:  # still running: algo and env from args.yml, wall time from the monitor file
        for args_path in run_dir.glob("*/args.yml"):
            args = yaml.safe_load(args_path.read_text()) or {}
            summary = {"algo": args.get("algo"), "env": args.get("env")}
        monitor = run_dir / "0.monitor.csv"
        if monitor.exists():
            rows = monitor.read_text().strip().splitlines()
            if len(rows) > 2:
                summary["train_seconds"] = float(rows[-1].split(",")[2])
    command = command_path.read_text().strip() if command_path.exists() else ""
    env_id = str(summary.get("env") or run_dir.name.rsplit("_", 1)[0])
    return Curve(label, env_id, np.asarray(data["timesteps"]), success, results.mean(axis=1),
                 results.shape[1], summary, command)


def plot_curves(curves: list[Curve], path: Path, title: str) -> None:
    """Success rate (left) and mean evaluation return (right) vs env steps, one line per run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_s, ax_r) = plt.subplots(1, 2, figsize=(11, 4))
    for c in curves:
        name = f"{c.label}: {c.env_id}"
        ax_s.plot(c.steps, 100 * c.success, marker="o", ms=3, label=name)
        ax_r.plot(c.steps, c.mean_return, marker="o", ms=3, label=name)
    ax_s.set(xlabel="env steps", ylabel="success rate (%)", ylim=(-3, 103), title="deterministic evaluation")
    ax_r.set(xlabel="env steps", ylabel="mean return", title="(returns are not comparable across envs)")
    for ax in (ax_s, ax_r):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def markdown_table(curves: list[Curve], log_folder: Path | None = None) -> str:
    """Markdown: one summary row per run, then success rate at every evaluation point (``log_folder``, a path of
    this machine, is written ``<output dir>`` in the commands)."""
    lines = [
        "| run | env | algo | steps | best eval success | last eval success | final eval success "
        "(episodes) | train time (s) | steps/s |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for c in curves:
        s = c.summary
        ev = s.get("eval") or {}
        final = ev.get("success_rate")
        final_txt = "n/a" if final is None else f"{100 * final:.0f}% ({ev.get('n_episodes', '?')})"
        best = np.nanmax(c.success) if np.isfinite(c.success).any() else float("nan")
        n_steps = int(s.get("n_timesteps", c.steps[-1]))
        seconds = float(s.get("train_seconds", float("nan")))
        fps = float(s.get("fps", n_steps / seconds if seconds > 0 else float("nan")))
        lines.append(
            f"| {c.label} | `{c.env_id}` | {s.get('algo', '?')} | {n_steps} "
            f"| {100 * best:.0f}% | {100 * c.success[-1]:.0f}% | {final_txt} | {seconds:.0f} | {fps:.0f} |"
        )
    lines += ["", f"Success rate (%) at each evaluation ({curves[0].n_episodes} deterministic episodes):", ""]
    steps = sorted({int(t) for c in curves for t in c.steps})
    lines.append("| steps | " + " | ".join(c.label for c in curves) + " |")
    lines.append("|---:|" + "---:|" * len(curves))
    for t in steps:
        cells = []
        for c in curves:
            hit = np.flatnonzero(c.steps == t)
            cells.append(f"{100 * c.success[hit[0]]:.0f}" if hit.size else "")
        lines.append(f"| {t} | " + " | ".join(cells) + " |")
    lines += ["", "Commands:", ""] + [f"- {c.label}: `{_portable(c.command, log_folder)}`" for c in curves if c.command]
    return "\n".join(lines) + "\n"


def _portable(command: str, log_folder: Path | None) -> str:
    """``command`` with ``log_folder`` (absolute or as given) written ``<output dir>``."""
    if log_folder is None:
        return command
    for form in sorted({str(log_folder.resolve()), str(log_folder)}, key=len, reverse=True):
        command = command.replace(form, "<output dir>")
    return command


def report(runs: list[tuple[str, str]], out: Path, title: str, note: str = "", log_folder: Path | None = None) -> str:
    """Write ``<out>.png`` and ``<out>.md`` for ``(label, run_dir)`` pairs; return the Markdown (``note``: a
    paragraph after the title; ``log_folder``: written ``<output dir>`` in the commands)."""
    curves = [load_curve(label, run_dir) for label, run_dir in runs]
    plot_curves(curves, out.with_suffix(".png"), title)
    text = f"# {title}\n\n" + (f"{note}\n" if note else "") + markdown_table(curves, log_folder)
    out.with_suffix(".md").write_text(text)
    return text


def _train_cmd(
    python: str,
    algo: str,
    env: str,
    args: argparse.Namespace,
    extra: list[str],
    conf: Path | None = None,
    log_folder: Path | None = None,
) -> list[str]:
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


def _train_both(
    args: argparse.Namespace, ours_env: str, panda_env: str, conf: Path, log_folder: Path, suffix: str = ""
) -> list[tuple[str, str]]:
    """Train ours and panda-gym's env concurrently; ``(label, run_dir)`` of both (labels end in ``suffix``)."""
    log_folder.mkdir(parents=True, exist_ok=True)
    jobs = {
        "ours": (ours_env, _train_cmd(sys.executable, args.algo, ours_env, args, [], conf, log_folder)),
        "panda-gym": (
            panda_env,
            _train_cmd(
                args.panda_python, args.algo, panda_env, args, ["--gym-packages", "panda_gym"], conf, log_folder
            ),
        ),
    }
    procs = {}
    for label, (_, cmd) in jobs.items():
        log = (log_folder / f"{label}.log").open("w")
        print(f"[{label}{suffix}] {shlex.join(cmd)}  (log: {log.name})", flush=True)
        procs[label] = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT.parent)
        if getattr(args, "sequential", False):
            procs[label].wait()
        time.sleep(2)  # distinct run dirs are guaranteed anyway; this keeps the start order readable
    codes = {label: p.wait() for label, p in procs.items()}
    print(f"exit codes{suffix}: {codes}", flush=True)
    return [(label + suffix, str(_newest_run(log_folder, args.algo, env))) for label, (env, _) in jobs.items()]


def run(args: argparse.Namespace) -> None:
    """Train ours and panda-gym's env concurrently, then write the report."""
    runs = _train_both(args, args.ours_env, args.panda_env, args.conf, args.log_folder)
    print(report(runs, args.out, args.title or _title(args), log_folder=args.log_folder))


def pair_config(conf: Path, pair: Pair, path: Path) -> dict[str, Any]:
    """Write the two entries of ``pair`` from the zoo file ``conf`` to ``path``, under the env ids trained."""
    data = load_yaml(conf) or {}
    missing = [key for key in (pair.ours_entry, pair.panda_env) if key not in data]
    if missing:
        raise SystemExit(f"{conf} has no entry {missing[0]!r}")
    entries = {pair.ours_env: data[pair.ours_entry], pair.panda_env: data[pair.panda_env]}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(
        f"# {pair.name} pair of {conf.name} (ours: entry {pair.ours_entry})\n"
        + yaml.safe_dump(entries, sort_keys=False)
    )
    return entries


def like(args: argparse.Namespace) -> None:
    """Like for like: train every pair asked for (:data:`LIKE_PAIRS` for ``like``, :data:`PICK_PAIRS` for
    ``pick``), then report all curves together."""
    pairs, note, title = (PICK_PAIRS, PICK_NOTE, _pick_title) if args.cmd == "pick" else (
        LIKE_PAIRS, LIKE_NOTE, _like_title)
    runs: list[tuple[str, str]] = []
    for key in args.pairs:
        pair = pairs[key]
        conf = args.log_folder / key / "config.yml"
        pair_config(args.conf, pair, conf)
        runs += _train_both(args, pair.ours_env, pair.panda_env, conf, args.log_folder / key, f" {pair.name}")
    print(report(runs, like_out(args.out, args.pairs, pairs), args.title or title(args), note, args.log_folder))


def like_out(out: Path, chosen: list[str], pairs: dict[str, Pair]) -> Path:
    """Report path of a ``like``/``pick`` run: the default one gets the chosen pairs' keys appended when not all
    pairs ran (``kuka_learning_random_dense``), so one pair's report never overwrites the report of all."""
    if out in (LIKE_OUT, PICK_OUT) and set(chosen) != set(pairs):
        return out.with_name(out.name + "_" + "_".join(chosen))
    return out


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


def _pick_title(args: argparse.Namespace) -> str:
    return f"{args.algo.upper()} + HER, {args.n_timesteps} steps, seed {args.seed}: Kuka vs panda-gym pick-and-place"


def _like_title(args: argparse.Namespace) -> str:
    return (
        f"{args.algo.upper()}, {args.n_timesteps} steps, seed {args.seed}: Kuka push vs panda-gym push, "
        "like for like (randomized workspace)"
    )


def _title(args: argparse.Namespace) -> str:
    fixed = " (fixed target)" if Path(args.conf).name == DEFAULT_CONF.name else ""
    return f"{args.algo.upper()}, {args.n_timesteps} steps, seed {args.seed}: Kuka push{fixed} vs panda-gym push"


def build_parser() -> argparse.ArgumentParser:
    """``run`` (train both, then report), ``like`` (like-for-like pairs) and ``report`` (from existing run dirs)."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="train ours and panda-gym's env, then report (fixed-target config by default)")
    r.add_argument("--ours-env", default=OURS_ENV)
    r.add_argument("--panda-env", default=PANDA_ENV)
    r.add_argument("-conf", "--conf", type=Path, default=DEFAULT_CONF)
    lk = sub.add_parser("like", help="like for like: sparse+HER and dense pairs in panda-gym's randomized workspace")
    lk.add_argument("-conf", "--conf", type=Path, default=LIKE_CONF)
    lk.add_argument("--pairs", nargs="+", choices=sorted(LIKE_PAIRS), default=list(LIKE_PAIRS))
    pk = sub.add_parser("pick", help="grasping pick-and-place: KukaPickAndPlace-v0 vs PandaPickAndPlace-v3, HER")
    pk.add_argument("-conf", "--conf", type=Path, default=PICK_CONF)
    pk.add_argument("--pairs", nargs="+", choices=sorted(PICK_PAIRS), default=list(PICK_PAIRS))
    for q in (r, lk, pk):
        q.add_argument("--algo", default="sac")
        q.add_argument("--panda-python", required=True, help="a Python that can import panda_gym (e.g. a venv's)")
        q.add_argument("-n", "--n-timesteps", type=int, default=500_000 if q is pk else 300_000)
        q.add_argument("--save-freq", type=int, default=50_000,
                       help="checkpoint (with the replay buffer) every N steps; an unfinished run continues with "
                            "sbagents.train -i; <= 0: none")
        q.add_argument("-f", "--log-folder", type=Path, required=True, help="where the runs go")
        q.add_argument("--seed", type=int, default=0)
        q.add_argument("--eval-freq", type=int, default=10_000)
        q.add_argument("--eval-episodes", type=int, default=20)
        q.add_argument("--final-eval-episodes", type=int, default=50)
        q.add_argument("--sequential", action="store_true", help="train the two runs one after the other")
    rep = sub.add_parser("report", help="plot and tabulate existing run dirs")
    rep.add_argument("--run", action="append", required=True, metavar="LABEL=RUN_DIR")
    rep.add_argument("--note", choices=["like", "pick"], default=None, help="the like-for-like paragraph to add")
    rep.add_argument("--log-folder", type=Path, default=None, help="written <output dir> in the commands")
    for q, out in ((r, DEFAULT_OUT), (lk, LIKE_OUT), (pk, PICK_OUT), (rep, DEFAULT_OUT)):
        q.add_argument("--out", type=Path, default=out, help="output path without suffix")
        q.add_argument("--title", default="")
    return p


def main(argv: list[str] | None = None) -> None:
    """CLI entry point."""
    args = build_parser().parse_args(argv)
    if args.cmd == "run":
        run(args)
        return
    if args.cmd in ("like", "pick"):
        like(args)
        return
    runs = []
    for item in args.run:
        label, sep, path = item.partition("=")
        if not sep:
            raise SystemExit(f"--run expects LABEL=RUN_DIR, got {item!r}")
        runs.append((label, path))
    note = {"like": LIKE_NOTE, "pick": PICK_NOTE, None: ""}[args.note]
    print(report(runs, args.out, args.title or "Kuka push vs panda-gym push", note, args.log_folder))


if __name__ == "__main__":
    main()
