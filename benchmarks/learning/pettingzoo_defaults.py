"""``pettingzoo-defaults``: the ``pettingzoo`` default entry of ``zoo_configs/ppo.yml`` on mpe2 envs that have no
entry of their own (``simple_reference_v3``, ``simple_push_v3``, ``simple_adversary_v3``), against random play and
the scripted references of :mod:`benchmarks.learning.mpe_references`, and the small search that chose the entry.

Scores are per *side* (:data:`~benchmarks.learning.mpe_references.SIDES`: the team of the cooperative
``simple_reference``; the adversary and the good agents of the mixed envs), a side's return being the sum of its
agents' returns. The trained run is one shared policy that plays every agent (padded observations with an agent-type
feature). For each side: **ours** is that side's return with the trained model on both sides (``python -m
sbagents.evaluate -n EPISODES --seed 10000 --json``, one env copy); **random** and **scripted** replace that side's
agents by uniform random actions or by the scripted controller, against the trained model's other side (in process,
``EPISODES`` episodes on 8 env copies seeded 10000 + i). A side learned *above random* when ours > random (the same
opponents).

Search (``--search-budget`` agent steps per run, seed ``--search-seed``, ``--search-episodes`` episodes): each
candidate of :data:`CANDIDATES` (``-params`` overrides of the entry) trains on each env; its score on an env is the
mean over sides of the normalized score ``(ours - random) / (scripted - random)``; the entry is the candidate with
the best mean over envs (in the search, ours is played in process on the random and scripted sides' episodes). Then
the entry itself trains at its own budget (or ``-n``) on every ``--seeds`` seed::

    python -m benchmarks run pettingzoo-defaults --seeds 0 1 2
    python -m benchmarks run pettingzoo-defaults --keep-search --seeds 3 --add   # another seed, search kept
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import Benchmark
from benchmarks.learning.mpe_references import SIDES, mixed_actor, side_returns, side_summary
from benchmarks.report import RESULTS_DIR, load_average, load_results, machine_info, recorded_argv

#: The envs (mpe2's, no entry of their own in ``zoo_configs/ppo.yml``).
ENVS: tuple[str, ...] = tuple(SIDES)
#: Search candidates: name -> ``-params`` overrides of the ``pettingzoo`` entry (each names the settings it changes
#: from the entry before the search, ``n_envs 8, n_steps 128, batch_size 512, n_epochs 10, learning_rate 3e-4,
#: gamma 0.99, gae_lambda 0.95, ent_coef 0.01, net_arch [64, 64]``, so the search does not depend on the entry it
#: chose; ``current``: that entry; ``bigbatch``: the entry since the search).
PREVIOUS: tuple[str, ...] = ("n_envs:8", "batch_size:512", "learning_rate:3.0e-4")
CANDIDATES: dict[str, tuple[str, ...]] = {
    "current": PREVIOUS,
    "bigbatch": ("n_envs:16", "batch_size:2048", "learning_rate:7.0e-4"),
    "normalized": (*PREVIOUS, "normalize:{norm_obs: true, norm_reward: true}"),
}
#: The evaluation episodes' first seed.
EVAL_SEED = 10_000
#: Env copies of the in-process evaluations (random or scripted sides against the model): one batched model call
#: per step for all of them.
COPIES = 8
RESULTS = "pettingzoo_defaults.json"


def cli(module: str, *args: str) -> subprocess.CompletedProcess[str]:
    """``python -m sbagents.<module> args`` (checked)."""
    return subprocess.run([sys.executable, "-m", f"sbagents.{module}", *args], capture_output=True, text=True,
                          check=True)


def train(env: str, seed: int, budget: int | None, params: Sequence[str], logs: Path) -> dict[str, Any]:
    """``python -m sbagents.train --algo ppo --env ENV`` with the shipped entry (plus ``params``); its summary."""
    n = ["-n", str(budget)] if budget is not None else []
    extra = ["-params", *params] if params else []
    cli("train", "--algo", "ppo", "--env", env, "--seed", str(seed), "-f", str(logs), *n, *extra,
        "--eval-freq", "-1", "--final-eval-episodes", "0", "--verbose", "0")
    run_dir = sorted((logs / "ppo").iterdir(), key=lambda p: p.stat().st_mtime)[-1]
    summary: dict[str, Any] = json.loads((run_dir / "summary.json").read_text())
    summary["exp_id"] = int(run_dir.name.rsplit("_", 1)[1])
    return summary


def evaluate_sides(env: str, logs: Path, exp_id: int, episodes: int, seed: int = EVAL_SEED,
                   copies: int = COPIES, cli_ours: bool = True) -> dict[str, Any]:
    """Per side: ours, and that side played randomly / by the script against the trained model's other sides (in
    process, on the evaluation's team VecEnv with ``copies`` copies, copy ``i`` seeded ``seed + i``); plus the team
    return.

    :param cli_ours: ours from ``python -m sbagents.evaluate --json`` (one env copy); else in process on the same
        episodes as the random and scripted sides (the search: no interpreter start per run).
    """
    from sbagents.core.run_dir import RunRef, load_run
    from sbagents.env_factory import make_team_vecs, normalize_for_eval
    from sbagents.multiagent.team_eval import model_actor, run_team_episodes, slot_agents, team_summary

    loaded = load_run(RunRef("ppo", env, logs, exp_id=exp_id))
    if set(loaded.models) != {"shared"}:
        raise ValueError(f"{env}: expected one shared model, got groups {sorted(loaded.models)}")
    venv = make_team_vecs(loaded.experiment, loaded.env, copies, None, vec_env="dummy")["shared"]
    venv = normalize_for_eval(venv, loaded.experiment, loaded.stats_paths.get("shared"), loaded.trust)
    agents = slot_agents(venv, "shared")
    model_act = model_actor(loaded.models["shared"], loaded.experiment.deterministic_eval)
    try:
        if cli_ours:
            ours = json.loads(cli("evaluate", "--algo", "ppo", "--env", env, "-f", str(logs), "--exp-id",
                                  str(exp_id), "-n", str(episodes), "--seed", str(seed), "--json"
                                  ).stdout.splitlines()[-1])
        else:
            ours = team_summary(run_team_episodes({"shared": venv}, {"shared": model_act}, episodes, seed))
        out: dict[str, Any] = {"team_return": round(float(ours["mean_return"]), 2),
                               "ours": {k: round(v, 2) for k, v in side_returns(env, ours).items()},
                               "random": {}, "scripted": {}}
        for side, members in SIDES[env].items():
            for play in ("random", "scripted"):
                players = {a: (play if a in members else "model") for a in agents}
                actor = mixed_actor(env, venv, agents, players, model_act, seed)
                summary = team_summary(run_team_episodes({"shared": venv}, {"shared": actor}, episodes, seed))
                out[play][side] = round(side_returns(env, summary)[side], 2)
    finally:
        venv.close()
    return out


def normalized_score(row: Mapping[str, Any]) -> float:
    """Mean over sides of ``(ours - random) / (scripted - random)`` (1: the script's level, 0: random's)."""
    scores = [(row["ours"][s] - row["random"][s]) / (row["scripted"][s] - row["random"][s]) for s in row["ours"]
              if row["scripted"][s] != row["random"][s]]
    return round(float(np.mean(scores)), 3) if scores else float("nan")


def search(envs: Sequence[str], candidates: Mapping[str, Sequence[str]], budget: int, seed: int, episodes: int,
           logs: Path) -> dict[str, Any]:
    """Every candidate on every env at ``budget``; their rows, scores and the best candidate (runs already in
    ``logs/<candidate>/<env>`` are evaluated, not trained again)."""
    rows: dict[str, dict[str, Any]] = {}
    for name, params in candidates.items():
        rows[name] = {}
        for env in envs:
            where = logs / name / env.rpartition(".")[2]
            if (where / "ppo").is_dir():
                run_dir = sorted((where / "ppo").iterdir())[-1]
                summary = json.loads((run_dir / "summary.json").read_text())
                summary["exp_id"] = int(run_dir.name.rsplit("_", 1)[1])
            else:
                summary = train(env, seed, budget, params, where)
            row = {"train_s": round(float(summary["train_seconds"]), 1), "n_timesteps": summary["n_timesteps"],
                   **evaluate_sides(env, where, summary["exp_id"], episodes, cli_ours=False)}
            row["score"] = normalized_score(row)
            rows[name][env] = row
            print(json.dumps({"candidate": name, "env": env, **row}), flush=True)
    means = {name: round(float(np.mean([r["score"] for r in by_env.values()])), 3) for name, by_env in rows.items()}
    return {"budget": budget, "seed": seed, "episodes": episodes, "candidates": {k: list(v) for k, v in
                                                                                  candidates.items()},
            "rows": rows, "mean_score": means, "best": max(means, key=lambda k: means[k])}


def baselines(env: str, episodes: int) -> dict[str, Any]:
    """Both sides random, and both scripted (no model), on the evaluation episodes."""
    agents = [a for members in SIDES[env].values() for a in members]
    out = {}
    for play in ("random", "scripted"):
        summary = side_summary(env, dict.fromkeys(agents, play), episodes, EVAL_SEED)
        out[play] = {"team_return": round(float(summary["mean_return"]), 2),
                     "sides": {k: round(v, 2) for k, v in summary["sides"].items()}}
    return out


def entry_settings() -> dict[str, Any]:
    """The shipped ``pettingzoo`` entry of ``zoo_configs/ppo.yml`` (what an env with no entry gets)."""
    from sbagents.core.zoo_config import default_config_path, load_yaml

    return dict(load_yaml(default_config_path("ppo"))["pettingzoo"])


def build_parser() -> argparse.ArgumentParser:
    """The benchmark's options."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks run pettingzoo-defaults",
                                     description="the pettingzoo default PPO entry on unseen mpe2 envs")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--envs", nargs="+", default=list(ENVS), choices=list(ENVS))
    parser.add_argument("-n", "--n-timesteps", type=int, default=None,
                        help="final training budget (default: the entry's n_timesteps)")
    parser.add_argument("--eval-episodes", type=int, default=1000)
    parser.add_argument("--search-budget", type=int, default=250_000, help="agent steps per search run")
    parser.add_argument("--search-episodes", type=int, default=200)
    parser.add_argument("--search-seed", type=int, default=0)
    parser.add_argument("--search-logs", default="", help="keep the search runs here (runs found there are "
                        "evaluated, not trained again); default: a temporary folder")
    parser.add_argument("--candidates", nargs="+", default=list(CANDIDATES), choices=list(CANDIDATES))
    parser.add_argument("--keep-search", action="store_true", help="no search: keep the saved results' search")
    parser.add_argument("--search-from", default="", metavar="RESULTS_JSON",
                        help="no search: take the search of these results (e.g. a --search-only run's)")
    parser.add_argument("--search-only", action="store_true",
                        help="the search alone (no final runs): choose the entry, then run with --search-from")
    parser.add_argument("--add", action="store_true", help="add these seeds' runs to the saved results' runs")
    parser.add_argument("--jobs", type=int, default=1, help="final runs trained at once (one core each)")
    return parser


def recorded_command(argv: Sequence[str]) -> str:
    """The command as the section records it: machine paths (``--search-logs``, ``--search-from``) as placeholders."""
    placeholders = {"--search-logs": "DIR", "--search-from": "RESULTS.json"}
    args = [placeholders.get(argv[i - 1] if i else "", a) for i, a in enumerate(argv)]
    return " ".join(["python -m benchmarks run pettingzoo-defaults", *map(shlex.quote, recorded_argv(args))])


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Search (unless ``--keep-search`` or ``--search-from``), then the entry on every env and seed; the results."""
    args = build_parser().parse_args(list(argv))
    command = recorded_command(argv)
    saved = load_results(RESULTS_DIR / RESULTS) if (args.keep_search or args.add) else {}
    with tempfile.TemporaryDirectory() as tmp:
        found: dict[str, Any] | None = None
        if not (args.keep_search or args.search_from):
            logs = Path(args.search_logs) if args.search_logs else Path(tmp) / "search"
            found = search(args.envs, {k: CANDIDATES[k] for k in args.candidates}, args.search_budget,
                           args.search_seed, args.search_episodes, logs)
            found["command"] = command
        final: dict[str, Any] = {}
        pairs = [] if args.search_only else [(env, seed) for env in args.envs for seed in args.seeds]

        def one(pair: tuple[str, int]) -> dict[str, Any]:
            env, seed = pair
            logs = Path(tmp) / "final" / env / str(seed)
            start = time.time()
            summary = train(env, seed, args.n_timesteps, (), logs)
            row = {"seed": seed, "n_timesteps": summary["n_timesteps"],
                   "train_s": round(float(summary["train_seconds"]), 1), "load": load_average(),
                   **evaluate_sides(env, logs, summary["exp_id"], args.eval_episodes),
                   "wall_s": round(time.time() - start, 1)}
            print(json.dumps({"env": env, **row}), flush=True)
            return row

        with ThreadPoolExecutor(max(1, args.jobs)) as pool:
            rows = list(pool.map(one, pairs))
        for env in [] if args.search_only else args.envs:
            runs = [row for (e, _), row in zip(pairs, rows, strict=True) if e == env]
            if args.add:
                kept = (saved.get("final") or {}).get(env, {}).get("runs", [])  # none yet: nothing to keep
                runs = sorted([r for r in kept if r["seed"] not in args.seeds] + runs, key=lambda r: r["seed"])
            final[env] = {"runs": runs, "baselines": baselines(env, args.eval_episodes)}
    if found is None:  # read at the end: a --search-only run may still be writing it when this one starts
        found = (load_results(Path(args.search_from)) if args.search_from else saved)["search"]
    # --add: the runs of earlier commands stay, and so do those commands
    earlier = (saved.get("commands") or [saved["command"]]) if args.add and saved.get("command") else []
    return {"envs": args.envs, "entry": entry_settings(), "eval_episodes": args.eval_episodes,
            "eval_seed": EVAL_SEED, "search": found, "final": final, "machine": machine_info(), "command": command,
            "commands": [*earlier, command]}


def _commands(result: Mapping[str, Any]) -> str:
    """``Command: `...``` or, for runs added by later commands (``--add``), every command in order."""
    commands = result.get("commands") or [result["command"]]
    if len(commands) == 1:
        return f"Command: `{commands[0]}`"
    return "Commands (each added its seeds' runs): " + "; then ".join(f"`{c}`" for c in commands)


def _fmt(value: float) -> str:
    return f"{value:.2f}"


def _mean_sd(values: Sequence[float]) -> str:
    return f"{np.mean(values):.2f} ± {np.std(values):.2f}" if len(values) > 1 else _fmt(values[0])


def render(result: Mapping[str, Any]) -> str:
    """The section of BENCHMARKS.md, from the results alone."""
    entry = ", ".join(f"{k} {v}" for k, v in result["entry"].items() if k not in ("policy",))
    episodes = result["eval_episodes"]
    steps = sorted({r["n_timesteps"] for block in result["final"].values() for r in block["runs"]})
    budget = (f" Budget: {', '.join(f'{n:,}' for n in steps)} agent steps per run (the entry's `n_timesteps` is "
              f"{result['entry']['n_timesteps']:,}; `-n` sets the benchmark's)." if steps else "")
    lines = ["## The `pettingzoo` default entry on unseen mpe2 envs", "",
             "The `pettingzoo` default PPO entry (what an env with no entry of its own gets: "
             f"{entry}) trained through `python -m sbagents.train --algo ppo --env ENV` on mpe2 envs that have no "
             f"entry, evaluated on {episodes} episodes (`python -m sbagents.evaluate -n {episodes} --seed "
             f"{result['eval_seed']} --json`). Per side (a side's return: the sum of its agents' returns): **ours** "
             "= the trained shared policy on every agent; **random** / **scripted** = that side played by uniform "
             "random actions / by the scripted controller of `benchmarks/learning/mpe_references.py`, against the "
             "trained policy's other side (8 env copies seeded 10000 + i; ours: the CLI's one copy seeded 10000). "
             "*Above random*: ours > random on every seed; random vs random and scripted vs scripted: no model. "
             f"{_commands(result)}.{budget}"]
    if result["final"]:
        lines += ["", "| env | side | random (vs ours) | ours (mean ± sd over seeds) | scripted (vs ours) | "
                  "above random | random vs random | scripted vs scripted | train s |",
                  "|---|---|---:|---:|---:|:---:|---:|---:|---:|"]
    for env in [e for e in result["envs"] if e in result["final"]]:
        block = result["final"][env]
        runs = block["runs"]
        for side in SIDES[env]:
            ours = [r["ours"][side] for r in runs]
            rand = [r["random"][side] for r in runs]
            scripted = [r["scripted"][side] for r in runs]
            above = sum(o > r for o, r in zip(ours, rand, strict=True))
            lines.append(f"| {env} | {side} | {_mean_sd(rand)} | {_mean_sd(ours)} | {_mean_sd(scripted)} | "
                         f"{above}/{len(runs)} | {_fmt(block['baselines']['random']['sides'][side])} | "
                         f"{_fmt(block['baselines']['scripted']['sides'][side])} | "
                         f"{np.mean([r['train_s'] for r in runs]):.0f} |")
    if result["final"]:
        lines += ["", "Per seed (side: random / ours / scripted; timesteps; training seconds; load average):", ""]
    for env in [e for e in result["envs"] if e in result["final"]]:
        for r in result["final"][env]["runs"]:
            sides = "; ".join(f"{s}: {_fmt(r['random'][s])} / {_fmt(r['ours'][s])} / {_fmt(r['scripted'][s])}"
                              for s in SIDES[env])
            lines.append(f"- {env} seed {r['seed']}: {sides}; {r['n_timesteps']:,} steps; {r['train_s']:.0f} s; "
                         f"load {r['load']}")
    found = result["search"]
    if not result["final"]:
        lines += ["", "No final runs yet (a `--search-only` run): the entry at its budget on `--seeds` is still to be "
                  "measured (`--search-from` / `--keep-search`)."]
    lines += ["", f"**The search that chose the entry** ({found['budget']:,} agent steps per run, 1 seed "
              f"({found['seed']}), {found['episodes']} evaluation episodes; `{found.get('command', '')}`): "
              "normalized score per env = mean over sides of (ours − random) / (scripted − random) (0: random's "
              f"level, 1: the script's); best mean: **{found['best']}**."
              + (f" The entry is **{found['chosen']}**: {found['chosen_why']}" if found.get("chosen") else ""), "",
              "| candidate | -params | " + " | ".join(e.rpartition(".")[2] for e in result["envs"]) + " | mean |",
              "|---|---|" + "---:|" * (len(result["envs"]) + 1)]
    for name, by_env in found["rows"].items():
        params = " ".join(found["candidates"][name]) or "(the entry before the search)"
        cells = " | ".join(_fmt(by_env[e]["score"]) if e in by_env else "-" for e in result["envs"])
        lines.append(f"| {name} | `{params}` | {cells} | {found['mean_score'][name]:.2f} |")
    lines += ["", "Search rows (side: random / ours / scripted, against the candidate's trained other side; training "
              "seconds):", ""]
    for name, by_env in found["rows"].items():
        for env, row in by_env.items():
            sides = "; ".join(f"{s}: {_fmt(row['random'][s])} / {_fmt(row['ours'][s])} / {_fmt(row['scripted'][s])}"
                              for s in row["ours"])
            lines.append(f"- {name}, {env}: {sides}; {row['train_s']:.0f} s")
    machine = result["machine"]
    lines += ["", f"Machine: {machine.get('cpu', '?')}, {machine.get('cores', '?')} cores, shared with other work "
              "while it ran (each final run's load average is listed with it; the search ran at load 4-7)."]
    return "\n".join(lines)


BENCHMARKS = (
    Benchmark(name="pettingzoo-defaults", kind="learning", results=RESULTS,
              summary="the pettingzoo default PPO entry on unseen mpe2 envs vs random and scripted sides, and the "
                      "search that chose it",
              run=run, render=render),
)
