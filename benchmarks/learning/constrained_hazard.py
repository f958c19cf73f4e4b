"""Constrained PPO on HazardGridWorld: unconstrained, fixed-penalty (book-style), PPO-Lagrangian and PID-Lagrangian.

Each run is exactly ``python -m sbagents.train --algo ppo --env sbagents/HazardGridWorld-v0 --seed S`` with the
shipped entry (zoo_configs/ppo.yml) and the method's flags (the same library call):

- ``ppo``: no flags (reward only);
- ``ppo -50 penalty``: ``--env-kwargs hazard_penalty:-50`` (the book's fixed penalty on every hazard step);
- ``ppo-lagrangian``: ``--constraint lagrangian --cost-limit L``;
- ``ppo-pid``: ``--constraint pid --cost-limit L``.

Each is then evaluated as ``python -m sbagents.evaluate ... --json`` does (greedy, ``--episodes`` episodes): mean
episode cost and the task return (reward without the penalty: the penalty run's return plus 50 x its cost, so rows
compare). The plot shows the multiplier and the rollouts' mean episode cost over training from each constrained
run's ``safety.json`` (``constraint.history``).

    python -m benchmarks run constrained-hazard [--seeds 0 1 2] [-n STEPS] [--cost-limit 0.1]

The plot goes to ``benchmarks/results/constrained_hazard.png`` (``--plot``).
"""

from __future__ import annotations

import argparse
import json
import shlex
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import Benchmark
from benchmarks.learning.seed_table import StatsRow, grouped_stats_table, stats_of
from benchmarks.report import RESULTS_DIR, recorded_argv, save_figure

SECTION = "constrained-hazard"
ENV = "sbagents/HazardGridWorld-v0"
PENALTY = -50.0
BEST_SAFE_RETURN = 87.0  # 14 steps over the top row (docs/envs.md)
#: Method -> (extra train flags as shown in the section, env kwargs, constraint).
METHODS: dict[str, tuple[str, dict[str, float], str | None]] = {
    "ppo": ("", {}, None),
    "ppo -50 penalty": (f"--env-kwargs hazard_penalty:{PENALTY:g}", {"hazard_penalty": PENALTY}, None),
    "ppo-lagrangian": ("--constraint lagrangian --cost-limit {limit}", {}, "lagrangian"),
    "ppo-pid": ("--constraint pid --cost-limit {limit}", {}, "pid"),
}


def run_one(method: str, seed: int, n_timesteps: int | None, cost_limit: float, episodes: int,
            logs: Path) -> dict[str, Any]:
    """Train one method on one seed through the ``train`` pipeline, then evaluate it greedily."""
    from sbagents.api import (
        ConstraintSpec,
        EvalOptions,
        EvaluateOptions,
        ExecOptions,
        OutputOptions,
        RunRef,
        TrainSpec,
        evaluate,
        train,
    )

    _, env_kwargs, constraint = METHODS[method]
    folder = logs / f"{method.replace(' ', '_')}_{seed}"
    features = [ConstraintSpec(constraint, cost_limit)] if constraint else []
    result = train(TrainSpec("ppo", ENV, n_timesteps, env_kwargs=env_kwargs),
                   OutputOptions(folder), EvalOptions(eval_freq=0, final_eval_episodes=0),
                   ExecOptions(seed=seed, verbose=0), features=features)
    report = evaluate(RunRef("ppo", ENV, folder), EvaluateOptions(n_episodes=episodes, deterministic=True, seed=0))
    cost = float(report["mean_cost"])
    safety = result.run_dir / "safety.json"
    history = json.loads(safety.read_text()).get("constraint", {}).get("history", []) if safety.exists() else []
    return {"method": method, "seed": seed, "return": float(report["mean_return"]) - env_kwargs.get(
                "hazard_penalty", 0.0) * cost, "cost": cost, "success": report["success_rate"],
            "train_s": float(result.summary["train_seconds"]), "n_timesteps": int(result.summary["n_timesteps"]),
            "multiplier": result.summary.get("constraint", {}).get("multiplier"), "history": history}


def plot(runs: list[dict[str, Any]], path: Path, cost_limit: float) -> None:
    """Multiplier (left) and the rollouts' mean episode cost (right) over timesteps, one line per constrained run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_m, ax_c) = plt.subplots(1, 2, figsize=(11, 4))
    colors = {"ppo-lagrangian": "tab:blue", "ppo-pid": "tab:orange"}
    for r in runs:
        if not r["history"]:
            continue
        steps = [h["timesteps"] for h in r["history"]]
        style = dict(color=colors.get(r["method"]), lw=1, alpha=0.8, label=f"{r['method']} seed {r['seed']}",
                     linestyle=["-", "--", ":", "-."][r["seed"] % 4])
        ax_m.plot(steps, [h["multiplier"] for h in r["history"]], **style)
        ax_c.plot(steps, [h["ep_cost"] for h in r["history"]], **style)
    ax_c.axhline(cost_limit, color="k", lw=1, label=f"cost limit {cost_limit:g}")
    ax_m.set(xlabel="timesteps", ylabel="Lagrange multiplier", title="multiplier")
    ax_c.set(xlabel="timesteps", ylabel="mean episode cost of the rollout", title="EpCost")
    for ax in (ax_m, ax_c):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("PPO-Lagrangian and PID-Lagrangian on HazardGridWorld")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def markdown(result: dict[str, Any]) -> str:
    """The BENCHMARKS.md section: return / cost per seed and their means, per method."""
    seeds, limit = result["seeds"], result["cost_limit"]
    budget = "the entry's n_timesteps" if result["n_timesteps"] is None else f"-n {result['n_timesteps']}"
    n_flag = "" if result["n_timesteps"] is None else f" -n {result['n_timesteps']}"
    lines = [
        "## Constrained PPO on HazardGridWorld (PPO-Lagrangian, PID-Lagrangian)", "",
        f"`python -m sbagents.train --algo ppo --env {ENV} --seed S{n_flag}` plus each row's flags, shipped entry "
        f"of zoo_configs/ppo.yml ({budget}: {result['steps']} steps per run), then `python -m sbagents.evaluate "
        f"--json` ({result['episodes']} greedy episodes). Cells: task return / mean episode cost (return without "
        f"the penalty; the best safe path returns {BEST_SAFE_RETURN:g} at cost 0, the hazard path 95 at cost 1, an "
        f"episode that never reaches the goal -50). Goal: share of runs whose greedy episodes reach the goal. "
        f"Command: `{result['command']}`; machine: 2 cores shared with other jobs, torch 1 thread; wall time "
        f"{result['wall_s']:.0f} s.", "",
        "| method | flags | " + " | ".join(f"seed {s}" for s in seeds)
        + " | mean return | mean cost | goal | cost <= limit, return within 10% | final multiplier | train s |",
        "|---|---|" + "---:|" * (len(seeds) + 6),
    ]
    for method, (flags, _, _) in METHODS.items():
        rows = [r for r in result["runs"] if r["method"] == method]
        if not rows:
            continue
        cells = [f"{r['return']:.0f} / {r['cost']:g}" for r in rows]
        ok = sum(r["cost"] <= limit and r["return"] >= 0.9 * BEST_SAFE_RETURN for r in rows)
        goal = sum((r["success"] or 0.0) >= 1.0 for r in rows)
        multipliers = [r["multiplier"] for r in rows if r["multiplier"] is not None]
        final = f"{min(multipliers):.1f}-{max(multipliers):.1f}" if multipliers else "-"
        lines.append(f"| {method} | `{flags.format(limit=f'{limit:g}') or '(none)'}` | " + " | ".join(cells)
                     + f" | {np.mean([r['return'] for r in rows]):.1f} | {np.mean([r['cost'] for r in rows]):.2f} | "
                     f"{goal}/{len(rows)} | {ok}/{len(rows)} | {final} | {np.mean([r['train_s'] for r in rows]):.0f} |")
    stats_rows: list[StatsRow] = []
    for method, stats in result["stats"].items():
        stats_rows += [(method, "task return", stats["return"], ".1f"),
                       (method, "mean episode cost", stats["cost"], ".2f")]
    lines += ["", *grouped_stats_table("method", stats_rows)]
    lines += ["", "![multiplier and EpCost over training](benchmarks/results/constrained_hazard.png)"]
    return "\n".join(lines)


def add_stats(result: dict[str, Any]) -> dict[str, Any]:
    """``result`` with ``stats[method]``: the task return and the mean episode cost over seeds."""
    stats = {}
    for method in METHODS:
        runs = [r for r in result["runs"] if r["method"] == method]
        if runs:
            stats[method] = {"return": stats_of([r["return"] for r in runs]),
                             "cost": stats_of([r["cost"] for r in runs])}
    return {**result, "stats": stats}


def build_parser() -> argparse.ArgumentParser:
    """The benchmark's options."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("-n", "--n-timesteps", type=int, default=None, help="budget (default: the entry's)")
    parser.add_argument("--cost-limit", type=float, default=0.1)
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--methods", nargs="+", choices=list(METHODS), default=list(METHODS))
    parser.add_argument("--plot", default=str(RESULTS_DIR / "constrained_hazard.png"), help="PNG ('' = none)")
    return parser


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Train and evaluate every (method, seed); the results of the section (and the plot)."""
    args = build_parser().parse_args(list(argv))
    start, runs = time.perf_counter(), []
    with tempfile.TemporaryDirectory() as logs:
        for method in args.methods:
            for seed in args.seeds:
                runs.append(run_one(method, seed, args.n_timesteps, args.cost_limit, args.episodes, Path(logs)))
                print(json.dumps({k: v for k, v in runs[-1].items() if k != "history"}), flush=True)
    kept = [a for i, a in enumerate(argv) if "--plot" not in {a, argv[i - 1] if i else ""}]
    result = {"command": shlex.join(["python", "-m", "benchmarks", "run", SECTION, *recorded_argv(kept)]),
              "seeds": args.seeds, "n_timesteps": args.n_timesteps, "steps": runs[0]["n_timesteps"],
              "cost_limit": args.cost_limit, "episodes": args.episodes,
              "wall_s": time.perf_counter() - start, "runs": runs}
    if args.plot:
        plot(runs, Path(args.plot), args.cost_limit)
    return add_stats(result)


BENCHMARKS = (
    Benchmark(name=SECTION, kind="learning", results="constrained_hazard.json",
              summary="PPO, fixed penalty, PPO-Lagrangian and PID-Lagrangian on HazardGridWorld: return and cost",
              run=run, render=markdown),
)
