"""PettingZoo learning benchmarks through the CLI with the shipped zoo configs: ``mpe2.simple_spread_v3`` (and its
centralized critic), ``mpe2.simple_tag_v3`` (per_group), ``pettingzoo.sisl.pursuit_v5`` and
``pettingzoo.butterfly.knights_archers_zombies_v11``, each against random play (and simple_spread against the
scripted controller of :mod:`benchmarks.team_baselines`).

Per task and seed: ``python -m sbagents.train --algo A --env E --seed S`` (periodic evaluations give the learning
curve), then ``python -m sbagents.evaluate -n EPISODES --seed 10000 --json`` on the final model. A task may train
several budgets (``-n``) of the same config: simple_spread's 5- and 10-minute runs. Writes
``benchmarks/results/pettingzoo_<task>.json``, a curve PNG and the task's section of ``BENCHMARKS.md``.

    python -m benchmarks.pettingzoo_learning spread --seeds 0 1 2
    python -m benchmarks.pettingzoo_learning tag pursuit kaz --seeds 0 1 2
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.speed import write_section
from benchmarks.team_baselines import baseline_summary, spread_assignment_actor


@dataclass
class Task:
    """One benchmark: an env and config trained through the CLI.

    :param budgets: ``-n`` values to train (None: the config's own ``n_timesteps``).
    :param train_args: extra ``python -m sbagents.train`` arguments (e.g. ``-params critic:centralized``).
    :param target: ``(budget index, min mean return)`` checks reported in the table.
    """

    title: str
    env: str
    algo: str = "ppo"
    budgets: tuple[int | None, ...] = (None,)
    train_args: tuple[str, ...] = ()
    eval_episodes: int = 100
    targets: dict[int, float] = field(default_factory=dict)
    metric: str | None = None  # a per-episode metric of the evaluation to report beside the team return


TASKS: dict[str, Task] = {
    "spread": Task("mpe2 simple_spread (3 agents, discrete)", "mpe2.simple_spread_v3", budgets=(None, -2),
                   eval_episodes=300, targets={0: -30.0, 1: -34.0}),
    "spread-ctde": Task("mpe2 simple_spread, centralized critic", "mpe2.simple_spread_v3",
                        train_args=("-params", "critic:centralized", "agent_id:true"), eval_episodes=300),
    "tag": Task("mpe2 simple_tag (per_group: 3 adversaries vs 1 agent)", "mpe2.simple_tag_v3",
                metric="catches"),
    "pursuit": Task("SISL pursuit (8 pursuers, 30 evaders)", "pettingzoo.sisl.pursuit_v5", eval_episodes=20),
    "kaz": Task("Butterfly knights_archers_zombies (vector observations)",
                "pettingzoo.butterfly.knights_archers_zombies_v11", eval_episodes=50),
}


def cli(module: str, *args: str) -> subprocess.CompletedProcess[str]:
    """``python -m sbagents.<module> args`` (checked)."""
    return subprocess.run([sys.executable, "-m", f"sbagents.{module}", *args], capture_output=True, text=True,
                          check=True)


def config_budget(task: Task) -> int:
    """The shipped config's ``n_timesteps`` for ``task``."""
    from sbagents.pipeline.env_names import resolve_env
    from sbagents.pipeline.experiment import build_experiment
    from sbagents.pipeline.options import TrainSpec

    return build_experiment(TrainSpec(task.algo, task.env), resolve_env(task.env)).n_timesteps


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
    curve = np.load(run_dir / "evaluations.npz")
    row = {"seed": seed, "n_timesteps": summary["n_timesteps"], "train_s": summary["train_seconds"],
           "mean_return": round(evaluation["mean_return"], 2), "std_return": round(evaluation["std_return"], 2),
           "metrics": evaluation["metrics"], "load": round(os.getloadavg()[0], 2),
           "curve": {"timesteps": curve["timesteps"].tolist(),
                     "mean_return": np.mean(curve["results"], axis=1).round(2).tolist()}}
    if task.metric == "catches":
        row["catches"] = round(catches(evaluation), 2)
        row["catches_vs_random_adversaries"] = round(_tag_random_adversaries(task, run_dir, logs), 2)
    return row


def _tag_random_adversaries(task: Task, run_dir: Path, logs: Path) -> float:
    """Catches per episode of random adversaries against the run's trained agent."""
    from sbagents.api import RunRef
    from sbagents.multiagent.team_eval import model_actor, run_team_episodes, slot_agents, team_summary
    from sbagents.pipeline.env_factory import make_team_vecs
    from sbagents.pipeline.run_dir import load_run
    from benchmarks.team_baselines import random_actor

    loaded = load_run(RunRef(task.algo, task.env, logs, exp_id=int(run_dir.name.rsplit("_", 1)[1])))
    venvs = make_team_vecs(loaded.experiment, loaded.env, 1, None, vec_env="dummy")
    actors = {g: random_actor(v, 0) if g == "adversary" else model_actor(loaded.models[g])
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


def markdown(name: str, task: Task, result: dict[str, Any]) -> str:
    """The task's section of BENCHMARKS.md."""
    base = ", ".join(f"{k} play {v['mean_return']:.2f}" for k, v in result["baselines"].items())
    extra = f" {' '.join(task.train_args)}" if task.train_args else ""
    lines = [f"## {task.title}", "",
             f"`python -m sbagents.train --algo {task.algo} --env {task.env}{extra}` with the shipped config "
             f"(budget `-n` as listed), greedy team evaluated on {task.eval_episodes} episodes (`python -m "
             f"sbagents.evaluate -n {task.eval_episodes} --seed 10000`). Baselines on the same episodes: {base}. "
             f"Command: `python -m benchmarks.pettingzoo_learning {name} --seeds "
             f"{' '.join(str(s) for s in result['seeds'])}`. Curve: `benchmarks/results/pettingzoo_{name}.png`.", ""]
    header = "| seed | timesteps | train s | team return |"
    header += " catches/episode | catches, random adversaries |" if task.metric == "catches" else ""
    lines += [header + " load |", "|" + "---:|" * (header.count("|") ) ]
    for row in result["runs"]:
        cells = f"| {row['seed']} | {row['n_timesteps']:,} | {row['train_s']:.0f} | {row['mean_return']:.2f} |"
        if task.metric == "catches":
            cells += f" {row['catches']:.2f} | {row['catches_vs_random_adversaries']:.2f} |"
        lines.append(cells + f" {row['load']} |")
    return "\n".join(lines)


def plot(name: str, task: Task, result: dict[str, Any], path: Path) -> None:
    """Team return against timesteps, one line per seed and budget, with the baselines as horizontal lines."""
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
    ax.set_ylabel("team return (greedy evaluation)")
    ax.set_title(task.title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_task(name: str, seeds: list[int], output: str, results_dir: Path) -> dict[str, Any]:
    """Every seed and budget of one task; writes its JSON, PNG and BENCHMARKS.md section."""
    task = TASKS[name]
    full = config_budget(task)
    budgets = [full if b is None else full // -b if b < 0 else b for b in task.budgets]
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for budget in budgets:
            for seed in seeds:
                row = run_one(task, seed, budget, Path(tmp) / f"n{budget}")
                print(json.dumps({k: v for k, v in row.items() if k != "curve"}), flush=True)
                runs.append(row)
    result = {"task": name, "env": task.env, "seeds": seeds, "budgets": budgets, "runs": runs,
              "baselines": {k: {"mean_return": round(v["mean_return"], 2), "std_return": round(v["std_return"], 2)}
                            for k, v in baselines(task).items()}}
    results_dir.mkdir(parents=True, exist_ok=True)
    (results_dir / f"pettingzoo_{name}.json").write_text(json.dumps(result, indent=2) + "\n")
    plot(name, task, result, results_dir / f"pettingzoo_{name}.png")
    text = markdown(name, task, result)
    print(text)
    if output:
        write_section(output, text, f"pettingzoo-{name}")
    return result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tasks", nargs="+", choices=sorted(TASKS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--output", default="BENCHMARKS.md", help="Markdown file to update ('' to skip)")
    parser.add_argument("--results", default="benchmarks/results", help="folder for the JSON and PNG files")
    args = parser.parse_args(argv)
    for name in args.tasks:
        run_task(name, args.seeds, args.output, Path(args.results))


if __name__ == "__main__":
    main()
