"""BenchMARL's MAPPO and IPPO beside our PPO on mpe2 ``simple_spread_v3`` (N=3, 25 steps, discrete actions,
local_ratio 0.5), same machine, same agent-step budgets (1M, 4M) and wall-time budgets (5, 10 min), evaluated on the
same 1,000 episodes::

    python -m benchmarks run benchmarl-spread                       # seed 0, both algorithms, both libraries
    python -m benchmarks run benchmarl-spread --seeds 0 1 --reuse   # keep finished runs of --work-dir

BenchMARL (on TorchRL) runs in a venv of its own (``--venv``, default ``.venv-benchmarl/`` at the repo root), created
on first use with CPU torch and the mpe2 we use; its training and evaluation are
``benchmarks/learning/benchmarl_venv.py`` run by that venv's python (``benchmarl_side``; our side:
``spread_ours``). One BenchMARL run per algorithm and seed serves every budget: it keeps the policy at the first batch
past each agent-step budget and at the last batch within each wall-time budget, and stops after the last budget (or at
``--max-seconds``).

Our side is the shipped ``mpe2.simple_spread_v3`` entry of ``zoo_configs/ppo.yml`` as it is when the benchmark runs:
``python -m sbagents.train --algo ppo --env mpe2.simple_spread_v3 --seed S --save-freq F`` (periodic evaluations
off, as BenchMARL's): one run at the entry's own budget (the 1M-step checkpoint, the 4M/final model, the last
checkpoint within 5 min), one at ``-n`` fitted to 10 minutes from that run's speed (the last checkpoint within 10 min,
or its final model). Every kept policy is evaluated greedily on mpe2's own env, episode ``k`` reset with seed
``10000 + k`` (``benchmarl_venv.spread_episodes``; our runs through the same episodes via sbagents' team VecEnv), and
our final models also with ``python -m sbagents.evaluate -n 1000 --seed 10000 --json`` (the CLI's episodes: one
seeded reset, then the env's RNG).
"""

from __future__ import annotations

import argparse
import json
import shlex
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.learning.benchmarl_side import (
    BENCHMARL_SETTINGS,
    ENV,
    N_AGENTS,
    REPO,
    ensure_venv,
    run_benchmarl,
    team_to_mappo,
    venv_versions,
)
from benchmarks.learning.seed_table import grouped_stats_table, stats_of
from benchmarks.learning.spread_ours import ours_entry, run_ours
from benchmarks.report import load_average, machine_info, recorded_argv


def build_parser() -> argparse.ArgumentParser:
    """The benchmark's options."""
    p = argparse.ArgumentParser(prog="python -m benchmarks run benchmarl-spread",
                                description=(__doc__ or "").splitlines()[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--algos", nargs="+", default=["mappo", "ippo"], choices=["mappo", "ippo"])
    p.add_argument("--venv", type=Path, default=REPO / ".venv-benchmarl", help="BenchMARL's venv (created if absent)")
    p.add_argument("--work-dir", type=Path, default=REPO / "logs" / "benchmarl-spread",
                   help="runs and kept policies of both libraries")
    p.add_argument("--reuse", action="store_true",
                   help="reuse finished runs and evaluations of --work-dir (BenchMARL: train.json; ours: "
                        "bench_run.json)")
    p.add_argument("--agent-budgets", type=int, nargs="+", default=[1_000_000, 4_000_000])
    p.add_argument("--second-budgets", type=float, nargs="+", default=[300.0, 600.0])
    p.add_argument("--max-seconds", type=float, default=1080.0,
                   help="stop a BenchMARL run here even if an agent-step budget is not reached")
    p.add_argument("--frames-per-batch", type=int, default=None, help="BenchMARL's on-policy batch (default 6000)")
    p.add_argument("--ours-n", type=int, default=None, help="-n of our first run (default: the entry's)")
    p.add_argument("--save-freq", type=int, default=100_000, help="our checkpoints, every N agent steps")
    p.add_argument("--n-eval", type=int, default=1000)
    p.add_argument("--eval-seed", type=int, default=10_000)
    p.add_argument("--no-cli-eval", dest="cli_eval", action="store_false",
                   help="skip the `sbagents.evaluate` column of our runs")
    p.add_argument("--note", default="", help="a sentence for the section (e.g. what else ran on the machine)")
    p.add_argument("--no-ours", action="store_true", help="BenchMARL only")
    p.add_argument("--no-fitted", dest="fitted", action="store_false",
                   help="no second run of ours fitted to the longest wall-time budget: the entry's run serves every "
                        "budget (its last checkpoint within each, or its final model when it ends sooner)")
    p.add_argument("--no-benchmarl", action="store_true", help="our side only")
    return p


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Both libraries on every seed; the results."""
    args = build_parser().parse_args(list(argv))
    if any(b <= 0 for b in args.agent_budgets) or any(s <= 0 for s in args.second_budgets):
        raise SystemExit("benchmarl-spread: budgets must be positive")
    work = args.work_dir.resolve()
    work.mkdir(parents=True, exist_ok=True)
    result: dict[str, Any] = {"env": ENV, "agent_budgets": args.agent_budgets, "second_budgets": args.second_budgets,
                              "n_eval": args.n_eval, "eval_seed": args.eval_seed, "seeds": args.seeds,
                              "max_seconds": args.max_seconds, "machine": machine_info(),
                              "command": " ".join(["python -m benchmarks run benchmarl-spread",
                                                   *map(shlex.quote, recorded_argv(list(argv)))]),
                              "benchmarl_settings": BENCHMARL_SETTINGS, "benchmarl": [], "ours": [], "note": args.note}
    if not args.no_benchmarl:
        python = ensure_venv(args.venv)
        result["benchmarl_versions"] = venv_versions(python)
        for seed in args.seeds:
            for algo in args.algos:
                row = run_benchmarl(python, algo, seed, work, args)
                print(json.dumps({k: v for k, v in row.items() if k != "settings"}), flush=True)
                result["benchmarl"].append(row)
    if not args.no_ours:
        result["ours_entry"] = ours_entry()
        for seed in args.seeds:
            row = run_ours(seed, work, args)
            print(json.dumps(row), flush=True)
            result["ours"].append(row)
    result["load_end"] = load_average()
    result["stats"] = [[group, budget, stats_of(values)] for (group, budget), values in seed_values(result).items()]
    return result


def seed_values(result: dict[str, Any]) -> dict[tuple[str, str], list[float]]:
    """(library / algorithm, budget) -> T of each seed, in table order."""
    values: dict[tuple[str, str], list[float]] = {}
    for row in table_rows(result):
        values.setdefault((row[0], row[2]), []).append(float(row[5]))
    return values


# --- rendering ------------------------------------------------------------------------------------------------


def _budget_label(label: str) -> str:
    """``agent_steps1000000`` / ``frames336000`` / ``seconds300`` -> the table's budget cell."""
    if label == "capped":
        return "time cap"
    if label.startswith("seconds"):
        return f"{float(label[len('seconds'):]) / 60:g} min"
    if label.startswith("frames"):
        return f"{int(label[len('frames'):]) * N_AGENTS / 1e6:g}M agent steps"
    return f"{int(label[len('agent_steps'):]) / 1e6:g}M agent steps"


def _rate(steps: float | None, seconds: float | None) -> str:
    return "-" if not steps or not seconds else f"{steps / seconds:,.0f}"


def table_rows(result: dict[str, Any]) -> list[list[str]]:
    """One row per library, algorithm, seed and kept policy."""
    rows = []
    for r in result["benchmarl"]:
        load = f"{r['load_start'][0]} / {r['load_end'][0]}"
        for k in r["kept"]:
            rows.append([f"BenchMARL {r['algo'].upper()}", str(r["seed"]), _budget_label(k.get("budget", k["label"])),
                         f"{k['agent_steps']:,}", f"{k['train_s']:.0f}", f"{k['team_return']:.2f}",
                         f"{team_to_mappo(k['team_return']):.1f}", "-",
                         _rate(k["agent_steps"], k["collection_s"]), _rate(k["agent_steps"], k["train_s"]), load])
    for seed_row in result["ours"]:
        for r in seed_row["runs"]:
            load = f"{r['load_start'][0]} / {r['load_end'][0]}"
            for k in r["kept"]:
                rows.append(["ours PPO (shipped entry)", str(seed_row["seed"]), _budget_label(k["label"]),
                             f"{k['agent_steps']:,}", f"{k['train_s']:.0f}", f"{k['team_return']:.2f}",
                             f"{team_to_mappo(k['team_return']):.1f}",
                             f"{k['cli_team_return']:.2f}" if "cli_team_return" in k else "-", "-",
                             _rate(k["agent_steps"], k["train_s"]), load])
    return rows


def render(result: dict[str, Any]) -> str:
    """The ``benchmarl-spread`` section from the results alone."""
    versions = result.get("benchmarl_versions", {})
    lines = [
        "## BenchMARL side by side: mpe2 simple_spread (N=3, 25 steps, discrete, local_ratio 0.5)", "",
        f"Command: `{result['command']}`. Machine: {result['machine']['cpu']}, {result['machine']['cores']} cores, "
        "shared with other work (load averages: 1-minute, at the start / end of each run); every process uses one "
        "torch thread. BenchMARL " + ", ".join(f"{k} {v}" for k, v in versions.items())
        + f"; ours: torch {result['machine']['torch']}, SB3 {result['machine']['stable_baselines3']}.", "",
        f"T: mean team return (sum of the 3 agents' 25-step returns) of the greedy team over the same "
        f"{result['n_eval']:,} episodes for every row (mpe2's parallel env, episode k reset with seed "
        f"{result['eval_seed']} + k); R = 2T - 75 is the scale of the MAPPO authors' logs (their -120 is T = -22.5). "
        "CLI T: `python -m sbagents.evaluate -n 1000 --seed 10000 --json` of the same model (one seeded reset, then "
        "the env's RNG: other episodes). A budget's policy: agent-step budgets keep the first policy at or past the "
        "budget (BenchMARL: the first 6,000-frame batch; ours: the first checkpoint, every 100,000 agent steps); "
        "wall-time budgets keep the last policy within it. BenchMARL counts frames as env (team) steps: agent steps "
        "= 3 x frames. Train s: BenchMARL from `experiment.run()` (experiment build excluded); ours `model.learn` "
        "(SB3's `train_seconds`). Collection: agent steps per second of collection time alone (BenchMARL: the time "
        "between a training step's end and the next batch); overall: agent steps per train second.", "",
        "| library / algorithm | seed | budget | agent steps | train s | T | R = 2T - 75 | CLI T | collection "
        "agent steps/s | overall agent steps/s | load |",
        "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    lines += ["| " + " | ".join(row) + " |" for row in table_rows(result)]
    capped = [r for r in result["benchmarl"] if (r.get("total") or {}).get("capped")]
    for r in capped:
        t = r["total"]
        reached = [_budget_label(k.get("budget", k["label"])) for k in r["kept"] if k["label"] != "capped"]
        lines += ["", f"BenchMARL {r['algo'].upper()} seed {r['seed']} was stopped at its time cap (--max-seconds "
                  f"{r.get('max_seconds', result['max_seconds']):g}) after {t['agent_steps']:,} agent steps "
                  f"({t['frames']:,} frames) "
                  f"in {t['train_s']:.0f} s; budgets reached: {', '.join(reached) or 'none'}; the others are missing "
                  "from the table."]
    for seed_row in result["ours"]:
        for r in seed_row["runs"]:
            lines += ["", f"Ours seed {seed_row['seed']}: a run of {r['n_timesteps']:,} agent steps in "
                      f"{r['train_s']:.0f} s ({r['fps']:,.0f} agent steps/s overall)"
                      + (", stopped at the time cap" if r["interrupted"] else "") + "."]
    if result.get("note"):
        lines += ["", result["note"]]
    lines += ["", *grouped_stats_table("library / algorithm", [
        (group, f"T, {budget}", stats, ".2f") for group, budget, stats in result["stats"]])]
    lines += ["", "Settings that differ (ours: the shipped entry as run; BenchMARL: its default configs):", "",
              "| setting | BenchMARL | ours |", "|---|---|---|"]
    entry = result.get("ours_entry", {})
    ours_cells = ours_settings(entry)
    for key, value in result["benchmarl_settings"].items():
        lines.append(f"| {key} | {value} | {ours_cells.get(key, '-')} |")
    return "\n".join(lines)


def ours_settings(entry: dict[str, Any]) -> dict[str, str]:
    """Our side of the settings table, from the entry's recorded hyperparameters (SB3's PPO defaults where the entry
    sets nothing)."""
    hp = entry.get("hyperparams") or {}
    if not hp:
        return {}
    team = entry.get("team") or {}
    pk = hp.get("policy_kwargs") or {}
    n_envs, n_steps = entry.get("n_envs"), hp.get("n_steps", 2048)
    known = {"policy", "policy_kwargs", "n_steps", "batch_size", "n_epochs", "learning_rate", "gamma", "gae_lambda",
             "ent_coef", "clip_range", "n_envs", "n_timesteps", "policies", "normalize", "max_grad_norm"}
    extra = {k: v for k, v in hp.items() if k not in known}
    critic = {"local": "the agent's own observation", "centralized": "centralized (all agents' observations)"}
    agent_steps = n_envs * n_steps * N_AGENTS if n_envs else None
    return {
        "network": (f"{str(pk['features_extractor_class']).rsplit(':', 1)[-1].rsplit('.', 1)[-1]} "
                    f"{pk.get('features_extractor_kwargs', {})}, then " if pk.get("features_extractor_class") else "")
                   + f"MLP {pk.get('net_arch', '64-64 (SB3 default)')}, {pk.get('activation_fn', 'tanh')}, "
                   "features shared by actor and critic",
        "parameter sharing": f"policies: {team.get('policies', hp.get('policies', '-'))}"
                             + (", agent id appended" if team.get("agent_id") else ""),
        "critic input": critic.get(str(team.get("critic", "local")), str(team.get("critic"))),
        "recurrent": "no",
        "normalization": f"VecNormalize: {entry.get('normalize')}; advantages normalized per minibatch (SB3)",
        "batch": f"{n_envs} envs x {n_steps} steps = {agent_steps:,} agent steps per iteration"
                 if agent_steps else "-",
        "epochs / minibatches": f"{hp.get('n_epochs', 10)} epochs, minibatch {hp.get('batch_size', 64)} agent steps",
        "lr": f"{hp.get('learning_rate', 3e-4)} (Adam eps 1e-5), grad-norm clip {hp.get('max_grad_norm', 0.5)}",
        "gamma / lambda": f"{hp.get('gamma', 0.99)} / {hp.get('gae_lambda', 0.95)}",
        "clip / entropy": f"{hp.get('clip_range', 0.2)} / {hp.get('ent_coef', 0.0)}",
        "episode": "25 steps",
        "actions": "discrete",
        "env": "sbagents' batched numpy copy of mpe2 simple_spread_v3 (training); mpe2's env (evaluation)"
               + (f"; other entry settings: {', '.join(f'{k}: {v}' for k, v in extra.items())}" if extra else ""),
    }


BENCHMARKS = (
    Benchmark(name="benchmarl-spread", kind="learning", results="benchmarl_spread.json",
              summary="BenchMARL MAPPO/IPPO (own venv) beside our PPO on mpe2 simple_spread: 1M/4M agent steps, "
                      "5/10 min, 1,000 episodes",
              run=run, render=render),
)
