"""PettingZoo learning benchmarks through the CLI with the shipped zoo configs: ``mpe2.simple_spread_v3`` (and its
centralized critic), ``mpe2.simple_tag_v3`` (per_group), ``pettingzoo.sisl.pursuit_v5`` and
``pettingzoo.butterfly.knights_archers_zombies_v11``, each against random play (and simple_spread against the
scripted controller of :mod:`benchmarks.team_baselines`).

Per task and seed: ``python -m sbagents.train --algo A --env E --seed S`` (periodic evaluations give the learning
curve), then ``python -m sbagents.evaluate -n EPISODES --seed 10000 --json`` on the final model. simple_spread also
evaluates the last checkpoint its run saved within 5 minutes of training (``--save-freq``), the same way. Writes
``benchmarks/results/pettingzoo_<task>.json``, a curve PNG and the task's section of ``BENCHMARKS.md``.

    python -m benchmarks.pettingzoo_learning spread --seeds 0 1 2
    python -m benchmarks.pettingzoo_learning tag pursuit kaz --seeds 0 1 2
    python -m benchmarks.pettingzoo_learning spread-ctde --seeds 1 2 --add    # beside the saved seed 0
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.report import write_section
from benchmarks.team_baselines import baseline_summary, spread_assignment_actor


@dataclass
class Task:
    """One benchmark: an env and config trained through the CLI.

    :param budgets: ``-n`` values to train (None: the config's own ``n_timesteps``).
    :param train_args: extra ``python -m sbagents.train`` arguments (e.g. ``-params critic:centralized``).
    """

    title: str
    env: str
    algo: str = "ppo"
    budgets: tuple[int | None, ...] = (None,)
    train_args: tuple[str, ...] = ()
    eval_episodes: int = 100
    metric: str | None = None  # a per-episode metric of the evaluation to report beside the team return
    checkpoint_seconds: float | None = None  # also evaluate the last checkpoint saved within this much training
    greedy_too: bool = False  # a config that evaluates stochastically: also report the greedy team's return
    note: str = ""  # what the numbers mean, printed under the table


TASKS: dict[str, Task] = {
    "spread": Task("mpe2 simple_spread (3 agents, discrete)", "mpe2.simple_spread_v3", eval_episodes=300,
                   train_args=("--save-freq", "100000"), checkpoint_seconds=300.0,
                   note="Targets: >= -30 within 10 minutes of training, >= -34 within 5 minutes (the checkpoint "
                        "columns: the last checkpoint saved within 300 s of `model.learn`, evaluated the same way). "
                        "The curves are the runs' periodic evaluations (a few episodes of each run's own eval env, "
                        "the same ones every time), so a curve's level depends on its episodes; the table's 300 "
                        "episodes are the same for every row."),
    "spread-ctde": Task("mpe2 simple_spread, centralized critic", "mpe2.simple_spread_v3",
                        train_args=("-params", "critic:centralized", "agent_id:true"), eval_episodes=300),
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
                "pettingzoo.butterfly.knights_archers_zombies_v11", budgets=(500_000,), eval_episodes=50,
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
    curve = np.load(run_dir / "evaluations.npz")
    row = {"seed": seed, "n_timesteps": summary["n_timesteps"], "train_s": summary["train_seconds"],
           "mean_return": round(evaluation["mean_return"], 2), "std_return": round(evaluation["std_return"], 2),
           "metrics": evaluation["metrics"], "load": round(os.getloadavg()[0], 2),
           "curve": {"timesteps": curve["timesteps"].tolist(),
                     "mean_return": np.mean(curve["results"], axis=1).round(2).tolist()}}
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
    from benchmarks.team_baselines import random_actor
    from sbagents.api import RunRef
    from sbagents.core.run_dir import load_run
    from sbagents.env_factory import make_team_vecs
    from sbagents.multiagent.team_eval import model_actor, run_team_episodes, slot_agents, team_summary

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


def _baseline_row(task: Task, summary: dict[str, Any]) -> dict[str, Any]:
    """What the JSON keeps of a baseline's summary."""
    row = {"mean_return": round(summary["mean_return"], 2), "std_return": round(summary["std_return"], 2)}
    if task.metric == "catches":
        row["catches"] = round(catches(summary), 2)
    return row


def markdown(name: str, task: Task, result: dict[str, Any]) -> str:
    """The task's section of BENCHMARKS.md."""
    base = ", ".join(f"{k} play {v['mean_return']:.2f}" + (f" ({v['catches']:.2f} catches/episode)"
                                                             if "catches" in v else "")
                     for k, v in result["baselines"].items())
    extra = f" {' '.join(task.train_args)}" if task.train_args else ""
    how = "greedy" if config_experiment(task).deterministic_eval else "sampling"
    lines = [f"## {task.title}", "",
             f"`python -m sbagents.train --algo {task.algo} --env {task.env}{extra}` with the shipped config "
             f"(budget `-n` as listed), {how} team evaluated on {task.eval_episodes} episodes (`python -m "
             f"sbagents.evaluate -n {task.eval_episodes} --seed 10000`). Baselines on the same episodes: {base}. "
             f"Command: `python -m benchmarks.pettingzoo_learning {name} --seeds "
             f"{' '.join(str(s) for s in result['seeds'])}`. Curve: `benchmarks/results/pettingzoo_{name}.png`.", ""]
    header = "| seed | timesteps | train s | team return |"
    header += " greedy team return |" if task.greedy_too else ""
    header += " catches/episode | catches, random adversaries |" if task.metric == "catches" else ""
    if task.checkpoint_seconds is not None:
        header += f" checkpoint <= {task.checkpoint_seconds:.0f} s: steps | train s | team return |"
    lines += [header + " load |", "|" + "---:|" * (header.count("|") ) ]
    for row in result["runs"]:
        cells = f"| {row['seed']} | {row['n_timesteps']:,} | {row['train_s']:.0f} | {row['mean_return']:.2f} |"
        cells += f" {row['greedy_return']:.2f} |" if task.greedy_too else ""
        if task.metric == "catches":
            cells += f" {row['catches']:.2f} | {row['catches_vs_random_adversaries']:.2f} |"
        if task.checkpoint_seconds is not None:
            ck = row["checkpoint"]
            cells += f" {ck['timesteps']:,} | {ck['train_s']} | {ck['mean_return']} |"
        lines.append(cells + f" {row['load']} |")
    if task.note:
        lines += ["", task.note]
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
    ax.set_ylabel(f"team return ({'greedy' if config_experiment(task).deterministic_eval else 'sampling'} "
                  "evaluation)")
    ax.set_title(task.title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_task(name: str, seeds: list[int], output: str, results_dir: Path, add: bool = False) -> dict[str, Any]:
    """Every seed and budget of one task; writes its JSON, PNG and BENCHMARKS.md section.

    :param add: keep the saved JSON's runs of other seeds (same budgets) and add these seeds' runs to them.
    """
    task = TASKS[name]
    full = config_experiment(task).n_timesteps
    budgets = [full if b is None else full // -b if b < 0 else b for b in task.budgets]
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for budget in budgets:
            for seed in seeds:
                row = run_one(task, seed, budget, Path(tmp) / f"n{budget}")
                print(json.dumps({k: v for k, v in row.items() if k != "curve"}), flush=True)
                runs.append(row)
    path = results_dir / f"pettingzoo_{name}.json"
    if add and path.exists():
        saved = json.loads(path.read_text())
        runs = sorted([r for r in saved["runs"] if r["seed"] not in seeds] + runs, key=lambda r: r["seed"])
        seeds = sorted({r["seed"] for r in runs})
    result = {"task": name, "env": task.env, "seeds": seeds, "budgets": budgets, "runs": runs,
              "baselines": {k: _baseline_row(task, v) for k, v in baselines(task).items()}}
    results_dir.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=2) + "\n")
    render(name, result, output, results_dir)
    return result


def render(name: str, result: dict[str, Any], output: str, results_dir: Path) -> None:
    """The task's PNG, and its section of ``output`` (printed; written unless ``output`` is empty)."""
    task = TASKS[name]
    plot(name, task, result, results_dir / f"pettingzoo_{name}.png")
    text = markdown(name, task, result)
    print(text)
    if output:
        write_section(output, text, f"pettingzoo-{name}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tasks", nargs="+", choices=sorted(TASKS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--output", default="BENCHMARKS.md", help="Markdown file to update ('' to skip)")
    parser.add_argument("--results", default="benchmarks/results", help="folder for the JSON and PNG files")
    parser.add_argument("--render-only", action="store_true",
                        help="no training: redraw the PNG and the BENCHMARKS.md section from the saved JSON")
    parser.add_argument("--add", action="store_true",
                        help="add these seeds to the saved JSON's runs (of the other seeds) instead of replacing them")
    args = parser.parse_args(argv)
    for name in args.tasks:
        if args.render_only:
            render(name, json.loads((Path(args.results) / f"pettingzoo_{name}.json").read_text()), args.output,
                   Path(args.results))
        else:
            run_task(name, args.seeds, args.output, Path(args.results), args.add)


if __name__ == "__main__":
    main()
