"""PettingZoo learning benchmarks through the CLI with the shipped zoo configs: ``mpe2.simple_spread_v3`` (and its
centralized critic), ``mpe2.simple_tag_v3`` (per_group), ``pettingzoo.sisl.pursuit_v5`` and
``pettingzoo.butterfly.knights_archers_zombies_v11``, each against random play (and simple_spread against the
scripted controller of :mod:`benchmarks.team_baselines`).

Per task and seed: ``python -m sbagents.train --algo A --env E --seed S`` (periodic evaluations give the learning
curve), then ``python -m sbagents.evaluate -n EPISODES --seed 10000 --json`` on the final model. simple_spread also
evaluates the last checkpoint its run saved within 5 minutes of training (``--save-freq``), the same way. One
benchmark per task (``pettingzoo-<task>``, results ``benchmarks/results/pettingzoo_<task>.json``, a curve PNG beside
it); the results hold per-seed statistics (mean +- std, IQM with its 95% bootstrap interval) of each metric::

    python -m benchmarks run pettingzoo-spread --seeds 0 1 2
    python -m benchmarks run pettingzoo-spread-ctde --seeds 1 2 --add    # beside the saved seed 0
    python -m benchmarks run pettingzoo-tag --replot                     # redraw the PNG from the saved results
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import Benchmark
from benchmarks.learning.seed_table import StatRow, iqm_note, metric_stats, stats_table
from benchmarks.learning.team_baselines import baseline_summary, spread_assignment_actor
from benchmarks.report import RESULTS_DIR, load_results, machine_info, recorded_argv, save_figure


@dataclass
class Task:
    """One benchmark: an env and config trained through the CLI.

    :param budget: ``-n`` to train (None: the config's own ``n_timesteps``).
    :param train_args: extra ``python -m sbagents.train`` arguments (e.g. ``-params critic:centralized``).
    """

    title: str
    env: str
    algo: str = "ppo"
    budget: int | None = None
    train_args: tuple[str, ...] = ()
    eval_episodes: int = 100
    metric: str | None = None  # a per-episode metric of the evaluation to report beside the team return
    checkpoint_seconds: float | None = None  # also evaluate the last checkpoint saved within this much training
    greedy_too: bool = False  # a config that evaluates stochastically: also report the greedy team's return
    note: str = ""  # what the numbers mean, printed under the table
    metric_keys: tuple[str, ...] = ()  # the env's declared episode metrics shown beside the team return
    mappo_scale: bool = False  # also show R = 2T - 75, the MAPPO repository's simple_spread score of team return T


TASKS: dict[str, Task] = {
    "spread": Task("mpe2 simple_spread (3 agents, discrete)", "mpe2.simple_spread_v3", eval_episodes=1000,
                   train_args=("--save-freq", "100000"), checkpoint_seconds=300.0,
                   metric_keys=("collisions", "landmarks_covered"), mappo_scale=True,
                   note="Target: T >= -22.5 within 10 minutes of training on 2 cores, MAPPO's level (the MAPPO "
                        "authors' repository reports about -120 on its scale R, which counts each agent's collision "
                        "with itself and sums the shared reward over agents: R = 2T - 75 exactly, so -120 is "
                        "T = -22.5; it takes 20M env steps = 60M agent steps there). collisions: colliding agent "
                        "pairs per step, summed over the episode; covered: landmarks whose nearest agent is within "
                        "0.1 at the last step. The checkpoint columns: the last checkpoint saved within 300 s of "
                        "`model.learn`, evaluated the same way. With `--jobs 2` two seeds train at once, one core "
                        "each (torch one thread, numpy env); the load column counts other work on the machine too. "
                        "The curves are the runs' periodic evaluations (a few episodes of each run's own eval env, "
                        "the same ones every time), so a curve's level depends on its episodes; the table's "
                        "evaluation episodes are the same for every row and for the baselines."),
    "spread-ctde": Task("mpe2 simple_spread, centralized critic", "mpe2.simple_spread_v3",
                        train_args=("-params", "critic:centralized", "agent_id:true"), eval_episodes=300,
                        note="The saved runs predate the current simple_spread entry: they used the previous one "
                             "(plain MLP, 16 teams x 100 steps, ent_coef 0.01, 300 evaluation episodes). The "
                             "`centralized` row of spread-ablation measures the centralized critic with the current "
                             "entry's other settings."),
    "tag": Task("mpe2 simple_tag (per_group: 3 adversaries vs 1 agent)", "mpe2.simple_tag_v3",
                metric="catches",
                note="Team return sums all four agents (adversaries +10 per catch each, the agent -10), so it is not "
                     "a score of either side. Catches per episode: the trained adversaries against the trained "
                     "agent; random adversaries against the same trained agent; random against random."),
    "pursuit": Task("SISL pursuit (8 pursuers, 30 evaders)", "pettingzoo.sisl.pursuit_v5", eval_episodes=20,
                    train_args=("--eval-freq", "500000", "--eval-episodes", "4"), greedy_too=True,
                    note="Team return sums the 8 pursuers' rewards: +5 to each pursuer of a catch, +0.01 per evader "
                         "touched, -0.1 per step while evaders remain; 500 steps unless all 30 are caught first. The "
                         "shipped config evaluates the policy as it acts (sampled actions, `deterministic_eval: "
                         "false`): a pursuer that sees no evader must wander, which a greedy memoryless policy cannot "
                         "(the greedy column, `evaluate --deterministic`, shows it). Trained on the batched pursuit "
                         "(`sbagents.batched.pursuit`, step for step the PettingZoo env)."),
    "kaz": Task("Butterfly knights_archers_zombies (vector observations)",
                "pettingzoo.butterfly.knights_archers_zombies_v11", budget=500_000, eval_episodes=50,
                note="Team return = zombies killed per episode (+1 per kill); an episode ends when a zombie reaches "
                     "the bottom or every agent is dead.",
                train_args=("--eval-freq", "100000", "--eval-episodes", "5")),
}


def cli(module: str, *args: str) -> subprocess.CompletedProcess[str]:
    """``python -m sbagents.<module> args`` (checked)."""
    return subprocess.run([sys.executable, "-m", f"sbagents.{module}", *args], capture_output=True, text=True,
                          check=True)


def config_experiment(task: Task) -> Any:
    """The shipped config's :class:`~sbagents.core.experiment.Experiment` for ``task``."""
    from sbagents.core.env_names import resolve_env
    from sbagents.core.experiment import build_experiment
    from sbagents.core.options import TrainSpec

    return build_experiment(TrainSpec(task.algo, task.env), resolve_env(task.env))


def catches(summary: dict[str, Any]) -> float:
    """simple_tag: adversary-agent collisions per episode (every adversary gets +10 per collision)."""
    return float(summary["metrics"]["per_agent_return"]["adversary_0"]) / 10.0


def run_one(task: Task, seed: int, budget: int | None, logs: Path) -> dict[str, Any]:
    """Train and evaluate one seed at one budget; returns its row."""
    n = ["-n", str(budget)] if budget is not None else []
    cli("train", "--algo", task.algo, "--env", task.env, "--seed", str(seed), "-f", str(logs), *n, *task.train_args,
        "--final-eval-episodes", "0")
    run_dir = sorted((logs / task.algo).iterdir(), key=lambda p: p.stat().st_mtime)[-1]
    summary = json.loads((run_dir / "summary.json").read_text())
    evaluation = json.loads(cli("evaluate", "--algo", task.algo, "--env", task.env, "-f", str(logs), "-n",
                                str(task.eval_episodes), "--seed", "10000", "--json").stdout.splitlines()[-1])
    curve = _curve(run_dir)
    row = {"seed": seed, "n_timesteps": summary["n_timesteps"], "train_s": summary["train_seconds"],
           "mean_return": round(evaluation["mean_return"], 2), "std_return": round(evaluation["std_return"], 2),
           "metrics": evaluation["metrics"], "load": round(os.getloadavg()[0], 2),
           "curve": curve, **{k: round(float(evaluation["metrics"][k]), 3) for k in task.metric_keys}}
    if task.greedy_too:
        greedy = json.loads(cli("evaluate", "--algo", task.algo, "--env", task.env, "-f", str(logs), "-n",
                                str(task.eval_episodes), "--seed", "10000", "--deterministic", "--json"
                                ).stdout.splitlines()[-1])
        row["greedy_return"] = round(greedy["mean_return"], 2)
    if task.checkpoint_seconds is not None:
        row["checkpoint"] = _evaluate_checkpoint(task, run_dir, summary, logs)
    if task.metric == "catches":
        row["catches"] = round(catches(evaluation), 2)
        row["catches_vs_random_adversaries"] = round(_tag_random_adversaries(task, run_dir, logs), 2)
    return row


def with_params(train_args: Sequence[str], params: Sequence[str]) -> list[str]:
    """``train_args`` with more ``-params`` overrides (merged into its own ``-params`` when it has one)."""
    args = list(train_args)
    if not params:
        return args
    if "-params" not in args:
        return [*args, "-params", *params]
    at = args.index("-params") + 1
    return args[:at] + list(params) + args[at:]


def _curve(run_dir: Path) -> dict[str, list[float]]:
    """The run's periodic evaluations (empty when the budget ended before the first one)."""
    path = run_dir / "evaluations.npz"
    if not path.exists():
        return {"timesteps": [], "mean_return": []}
    curve = np.load(path)
    return {"timesteps": curve["timesteps"].tolist(),
            "mean_return": np.mean(curve["results"], axis=1).round(2).tolist()}


def _evaluate_checkpoint(task: Task, run_dir: Path, summary: dict[str, Any], logs: Path) -> dict[str, Any]:
    """The last checkpoint saved within ``task.checkpoint_seconds`` of training, evaluated as the final model is.

    A checkpoint's training time is ``train_seconds`` minus the time between it and the final model's save, so it
    counts ``model.learn`` up to that checkpoint (periodic evaluations included), as ``train_seconds`` does.
    """
    from sbagents.core.run_dir import saved_checkpoints

    final = run_dir / f"{summary['env']}.zip"
    assert task.checkpoint_seconds is not None
    times = {steps: summary["train_seconds"] - (final.stat().st_mtime - p.stat().st_mtime)
             for steps, p in saved_checkpoints(run_dir).items()}
    within = [steps for steps, t in times.items() if t <= task.checkpoint_seconds]
    if not within:
        return {"timesteps": 0, "train_s": None, "mean_return": None}
    steps = max(within)
    evaluation = json.loads(cli("evaluate", "--algo", task.algo, "--env", task.env, "-f", str(logs),
                                "--exp-id", run_dir.name.rsplit("_", 1)[1], "--load-checkpoint", str(steps),
                                "-n", str(task.eval_episodes), "--seed", "10000", "--json").stdout.splitlines()[-1])
    return {"timesteps": steps, "train_s": round(times[steps], 1), "mean_return": round(evaluation["mean_return"], 2)}


def _tag_random_adversaries(task: Task, run_dir: Path, logs: Path) -> float:
    """Catches per episode of random adversaries against the run's trained agent."""
    from benchmarks.learning.team_baselines import random_actor
    from sbagents.api import RunRef
    from sbagents.callbacks.episodes import stateless
    from sbagents.core.run_dir import load_run
    from sbagents.env_factory import make_team_vecs
    from sbagents.multiagent.team_eval import model_actor, run_team_episodes, slot_agents, team_summary

    loaded = load_run(RunRef(task.algo, task.env, logs, exp_id=int(run_dir.name.rsplit("_", 1)[1])))
    venvs = make_team_vecs(loaded.experiment, loaded.env, 1, None, vec_env="dummy")
    actors = {g: stateless(random_actor(v, 0)) if g == "adversary" else model_actor(loaded.models[g])
              for g, v in venvs.items()}
    try:
        episodes = run_team_episodes(venvs, actors, task.eval_episodes, 10_000)
        return catches(team_summary(episodes, {g: slot_agents(v, g) for g, v in venvs.items()}))
    finally:
        next(iter(venvs.values())).close()


def baselines(task: Task) -> dict[str, Any]:
    """Random play (and simple_spread's scripted controller) on the task's evaluation episodes."""
    out = {"random": baseline_summary(task.env, {}, "random", task.eval_episodes, 10_000)}
    if task.env == "mpe2.simple_spread_v3":
        out["scripted"] = baseline_summary(task.env, {}, "scripted", task.eval_episodes, 10_000,
                                           lambda _v: spread_assignment_actor(3))
    return out


def _baseline_row(task: Task, summary: dict[str, Any]) -> dict[str, Any]:
    """What the JSON keeps of a baseline's summary."""
    row = {"mean_return": round(summary["mean_return"], 2), "std_return": round(summary["std_return"], 2),
           **{k: round(float(summary["metrics"][k]), 3) for k in task.metric_keys if k in summary.get("metrics", {})}}
    if task.metric == "catches":
        row["catches"] = round(catches(summary), 2)
    return row


#: Column labels of the env metrics a task shows.
_METRIC_LABELS = {"collisions": "collisions/episode", "landmarks_covered": "landmarks covered"}


def _cell(value: Any) -> str:
    return "-" if value is None else str(value)


def _header(task: Task) -> list[str]:
    """The per-seed table's header and separator rows."""
    header = "| seed | timesteps | train s | team return |"
    header += " R = 2T - 75 |" if task.mappo_scale else ""
    header += "".join(f" {_METRIC_LABELS.get(k, k)} |" for k in task.metric_keys)
    header += " greedy team return |" if task.greedy_too else ""
    header += " catches/episode | catches, random adversaries |" if task.metric == "catches" else ""
    if task.checkpoint_seconds is not None:
        header += f" checkpoint <= {task.checkpoint_seconds:.0f} s: steps | train s | team return |"
    return [header + " load |", "|" + "---:|" * header.count("|")]


def _row(task: Task, row: dict[str, Any]) -> str:
    """One seed's table row."""
    cells = f"| {row['seed']} | {row['n_timesteps']:,} | {row['train_s']:.0f} | {row['mean_return']:.2f} |"
    cells += f" {2 * row['mean_return'] - 75:.1f} |" if task.mappo_scale else ""
    cells += "".join(f" {row[k]:.2f} |" for k in task.metric_keys)
    cells += f" {row['greedy_return']:.2f} |" if task.greedy_too else ""
    if task.metric == "catches":
        cells += f" {row['catches']:.2f} | {row['catches_vs_random_adversaries']:.2f} |"
    if task.checkpoint_seconds is not None:
        ck = row["checkpoint"]
        cells += f" {ck['timesteps']:,} | {_cell(ck['train_s'])} | {_cell(ck['mean_return'])} |"
    return cells + f" {row['load']} |"


#: The statistics table's rows: label, key, format (metrics a task does not record are left out).
STAT_ROWS: tuple[StatRow, ...] = (("team return", "mean_return", ".2f"),
                                  *((_METRIC_LABELS[k], k, ".2f") for k in _METRIC_LABELS),
                                  ("greedy team return", "greedy_return", ".2f"),
                                  ("catches/episode", "catches", ".2f"),
                                  ("catches, random adversaries", "catches_vs_random_adversaries", ".2f"),
                                  ("checkpoint team return", "checkpoint_return", ".2f"), ("train s", "train_s", ".0f"))


def run_values(runs: list[dict[str, Any]]) -> dict[str, list[float]]:
    """Per-seed values of every metric of :data:`STAT_ROWS` that all runs have."""
    flat = [{**r, "checkpoint_return": (r.get("checkpoint") or {}).get("mean_return")} for r in runs]
    return {key: [float(r[key]) for r in flat] for _, key, _ in STAT_ROWS
            if all(r.get(key) is not None for r in flat)}


def _baseline_metrics(task: Task, row: dict[str, Any]) -> str:
    """`` (R -120.0; collisions/episode 1.73, ...)`` of a baseline, from what its results row holds."""
    parts = [f"R {2 * row['mean_return'] - 75:.1f}"] if task.mappo_scale else []
    parts += [f"{_METRIC_LABELS.get(k, k)} {row[k]:.2f}" for k in task.metric_keys if k in row]
    return f" ({'; '.join(parts)})" if parts else ""


def render_task(name: str, result: dict[str, Any]) -> str:
    """The task's section of BENCHMARKS.md, from its results alone."""
    task = TASKS[name]
    base = ", ".join(f"{k} play {v['mean_return']:.2f}" + (f" ({v['catches']:.2f} catches/episode)"
                                                             if "catches" in v else "") + _baseline_metrics(task, v)
                     for k, v in result["baselines"].items())
    train_args = with_params(task.train_args, result.get("params", []))
    extra = f" {' '.join(train_args)}" if train_args else ""
    episodes = result.get("eval_episodes", task.eval_episodes)
    lines = [f"## {task.title}", "",
             f"`python -m sbagents.train --algo {task.algo} --env {task.env}{extra}` with the shipped config "
             f"(budget `-n` as listed), {result['evaluation']} team evaluated on {episodes} episodes (`python -m "
             f"sbagents.evaluate -n {episodes} --seed 10000`). Baselines on the same episodes: {base}. "
             f"Command: `{result['command']}`. Curve: `benchmarks/results/pettingzoo_{name}.png`.", ""]
    lines += _header(task) + [_row(task, row) for row in result["runs"]]
    lines += ["", *stats_table(result["stats"], STAT_ROWS), "", iqm_note(len(result["runs"]))]
    if task.note:
        lines += ["", task.note]
    return "\n".join(lines)


def plot(task: Task, result: dict[str, Any], path: Path) -> None:
    """Team return against timesteps, one line per seed, with the baselines as horizontal lines (written to a
    temporary file renamed into place)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for row in result["runs"]:
        ax.plot(row["curve"]["timesteps"], row["curve"]["mean_return"], label=f"seed {row['seed']}, "
                f"{row['n_timesteps']:,} steps")
    for key, summary in result["baselines"].items():
        ax.axhline(summary["mean_return"], linestyle="--", color="grey" if key == "random" else "black", label=key)
    ax.set_xlabel("agent steps")
    ax.set_ylabel(f"team return ({result['evaluation']} evaluation)")
    ax.set_title(task.title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def build_parser(name: str) -> argparse.ArgumentParser:
    """The options of benchmark ``pettingzoo-<name>``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run pettingzoo-{name}",
                                     description=f"{TASKS[name].title}: PPO with the shipped config through the CLI")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("-n", "--n-timesteps", type=int, default=None,
                        help="training budget (default: the task's, else the config's n_timesteps)")
    parser.add_argument("--eval-episodes", type=int, default=None, help="evaluation episodes (default: the task's)")
    parser.add_argument("--params", nargs="+", default=[], metavar="KEY:VALUE",
                        help="more overrides of the zoo entry (train's -params), e.g. n_envs:2 n_steps:16")
    parser.add_argument("--plot", default=str(RESULTS_DIR / f"pettingzoo_{name}.png"),
                        help="curve PNG to write ('' to skip)")
    parser.add_argument("--jobs", type=int, default=1,
                        help="seeds trained at once (each run uses one core: torch one thread, numpy env)")
    parser.add_argument("--add", action="store_true",
                        help="add these seeds' runs to the saved results' runs of the other seeds")
    parser.add_argument("--replot", action="store_true",
                        help="no training: redraw the PNG from the saved results and return them unchanged")
    return parser


def _saved(name: str) -> dict[str, Any]:
    result: dict[str, Any] = load_results(RESULTS_DIR / f"pettingzoo_{name}.json")
    return result


def run_task(name: str, argv: Sequence[str]) -> dict[str, Any]:
    """Every seed of one task; its results (and its curve PNG)."""
    args = build_parser(name).parse_args(list(argv))
    task = TASKS[name]
    if args.replot:
        result = _saved(name)
        if args.plot:
            plot(task, result, Path(args.plot))
        return result
    task = replace(task, budget=args.n_timesteps or task.budget, eval_episodes=args.eval_episodes or task.eval_episodes,
                   train_args=tuple(with_params(task.train_args, args.params)))
    budget = task.budget or config_experiment(task).n_timesteps
    seeds = list(args.seeds)

    def one(seed: int, tmp: str) -> dict[str, Any]:
        row = run_one(task, seed, budget, Path(tmp) / f"s{seed}")
        print(json.dumps({k: v for k, v in row.items() if k not in ("curve", "metrics")}), flush=True)
        return row

    with tempfile.TemporaryDirectory() as tmp, ThreadPoolExecutor(max(1, args.jobs)) as pool:
        runs = list(pool.map(lambda seed: one(seed, tmp), seeds))
    if args.add:
        runs = sorted([r for r in _saved(name)["runs"] if r["seed"] not in seeds] + runs, key=lambda r: r["seed"])
        seeds = sorted({r["seed"] for r in runs})
    result = {"task": name, "env": task.env, "seeds": seeds, "budgets": [budget], "runs": runs,
              "baselines": {k: _baseline_row(task, v) for k, v in baselines(task).items()},
              "eval_episodes": task.eval_episodes, **({"params": args.params} if args.params else {}),
              "evaluation": "greedy" if config_experiment(task).deterministic_eval else "sampling",
              "command": " ".join([f"python -m benchmarks run pettingzoo-{name}",
                                   *map(shlex.quote, recorded_argv(list(argv)))]),
              "machine": machine_info(), "stats": metric_stats(run_values(runs))}
    if args.plot:
        plot(task, result, Path(args.plot))
    return result


BENCHMARKS = tuple(
    Benchmark(name=f"pettingzoo-{name}", kind="learning", results=f"pettingzoo_{name}.json",
              summary=f"{task.title}: PPO through the CLI with the shipped config vs random play, per seed",
              run=partial(run_task, name), render=partial(render_task, name))
    for name, task in TASKS.items()
)
