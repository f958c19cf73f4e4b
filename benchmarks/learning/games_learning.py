"""Turn-based games: self-play MaskablePPO through the CLI with the shipped configs, measured against fixed opponents,
and PettingZoo's own SB3 tutorial recipe side by side.

Per game and seed: ``python -m sbagents.train --algo ppo_mask --env GAME --seed S`` (shipped ``zoo_configs/
ppo_mask.yml`` entry), then ``python -m sbagents.evaluate --opponent O -n GAMES --seed 10000 --json`` on the final
model for each opponent (seats alternate). Bars (issue 16): tic-tac-toe no loss in 1,000 games against random and
>= 95% draws against minimax; connect four >= 98% wins against random and >= 60% against the heuristic within 15
minutes of training; texas hold'em mean chips per hand against random > 0 with its 95% interval above zero.

``games-tutorial``: PettingZoo's tutorial recipe (:mod:`benchmarks.learning.games_tutorial`, both the upstream and
the original 2023 wrapper) at its 20,480 steps, ours at the same budget (``-n 20480``), and ours at the shipped
budget (the saved rows of the game benchmarks, copied into the tutorial's results), all evaluated by the same matches.

    python -m benchmarks run games-connect4 --seeds 0 1 2        # also games-tictactoe, games-holdem
    python -m benchmarks run games-connect4 --seeds 1 --add      # a seed beside the saved ones
    python -m benchmarks run games-tutorial --seeds 0 1 2
    python -m benchmarks render games-tutorial                   # redraw a section from the saved results
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.learning.seed_table import StatsRow, grouped_stats_table, stats_of
from benchmarks.report import RESULTS_DIR, load_results, recorded_argv

EVAL_SEED = 10_000
#: ``--smoke``: games per match and training budget (a check that the benchmark runs end to end).
SMOKE_GAMES = 10
SMOKE_STEPS = 256


@dataclass(frozen=True)
class Budget:
    """How much a run plays: games per match (None: the game's own), training steps (None: the shipped config's or
    the tutorial's) and whether seed 0's rating plot is copied into ``benchmarks/results``."""

    games: int | None = None
    steps: int | None = None
    keep_elo: bool = True


#: ``--smoke``'s budget.
SMOKE = Budget(SMOKE_GAMES, SMOKE_STEPS, keep_elo=False)


@dataclass(frozen=True)
class Game:
    """One game: its env, the opponents it is measured against and how many games each."""

    title: str
    env: str
    opponents: tuple[str, ...]
    n_games: int
    stem: str


GAMES: dict[str, Game] = {
    "tictactoe": Game("tic-tac-toe", "pettingzoo.classic.tictactoe_v3", ("random", "minimax"), 1000, "tictactoe_v3"),
    "connect4": Game("connect four", "pettingzoo.classic.connect_four_v3", ("random", "heuristic"), 1000,
                     "connect_four_v3"),
    "holdem": Game("texas hold'em (limit, 2 players)", "pettingzoo.classic.texas_holdem_v4", ("random",), 10_000,
                   "texas_holdem_v4"),
}
#: The issue's bar per game: (text, row -> met).
BARS: dict[str, tuple[str, Any]] = {
    "tictactoe": ("no loss in 1,000 games against random, >= 95% draws against minimax",
                  lambda r: r["vs"]["random"]["loss_rate"] == 0 and r["vs"]["minimax"]["draw_rate"] >= 0.95),
    "connect4": (">= 98% wins against random and >= 60% against the heuristic within 900 s of training",
                 lambda r: r["vs"]["random"]["win_rate"] >= 0.98 and r["vs"]["heuristic"]["win_rate"] >= 0.6
                 and r["train_s"] <= 900),
    "holdem": ("mean chips per hand against random > 0 with the 95% interval above zero",
               lambda r: r["vs"]["random"]["reward_ci95"][0] > 0),
}
#: Games of the tutorial comparison (the tutorial's own game, and the one its test said "still loses").
TUTORIAL_GAMES = ("connect4", "tictactoe")


def cli(module: str, *args: str) -> subprocess.CompletedProcess[str]:
    """``python -m sbagents.<module> args`` (checked)."""
    return subprocess.run([sys.executable, "-m", f"sbagents.{module}", *args], capture_output=True, text=True,
                          check=True)


def match_row(summary: dict[str, Any]) -> dict[str, Any]:
    """What the JSON keeps of one match."""
    keys = ("n_games", "win_rate", "draw_rate", "loss_rate", "mean_reward", "reward_ci95", "illegal_moves")
    row = {k: summary[k] for k in keys}
    row["per_seat"] = {s: {k: v[k] for k in ("win_rate", "draw_rate", "loss_rate")}
                       for s, v in summary["per_seat"].items()}
    return row


def evaluate_run(game: Game, logs: Path, budget: Budget) -> dict[str, Any]:
    """The latest run in ``logs`` against each of the game's opponents."""
    out = {}
    for opponent in game.opponents:
        done = cli("evaluate", "--algo", "ppo_mask", "--env", game.env, "-f", str(logs), "--opponent", opponent,
                   "-n", str(budget.games or game.n_games), "--seed", str(EVAL_SEED), "--json")
        out[opponent] = match_row(json.loads(done.stdout.splitlines()[-1]))
    return out


def train_ours(game: Game, seed: int, logs: Path, budget: Budget, steps: int | None = None) -> dict[str, Any]:
    """Train with the shipped config (``-n steps`` if given, the budget's steps first) and evaluate; one row.
    Seed 0's rating plot at the shipped budget is copied to ``benchmarks/results/games_<game>_elo.png``."""
    steps = budget.steps or steps
    extra = ["-n", str(steps)] if steps is not None else []
    cli("train", "--algo", "ppo_mask", "--env", game.env, "--seed", str(seed), "-f", str(logs), *extra,
        "--final-eval-episodes", "0")
    run_dir = sorted((logs / "ppo_mask").iterdir(), key=lambda p: p.stat().st_mtime)[-1]
    summary = json.loads((run_dir / "summary.json").read_text())
    row = {"seed": seed, "n_timesteps": summary["n_timesteps"], "train_s": summary["train_seconds"],
           "load": round(os.getloadavg()[0], 2), "vs": evaluate_run(game, logs, budget)}
    if seed == 0 and steps is None and budget.keep_elo and (run_dir / "elo.png").exists():
        for suffix in ("png", "csv"):
            target = RESULTS_DIR / f"games_{game.stem}_elo.{suffix}"
            shutil.copyfile(run_dir / f"elo.{suffix}", target.with_name(f".{target.name}.tmp"))
            os.replace(target.with_name(f".{target.name}.tmp"), target)
    return row


def tutorial_rows(name: str, seeds: list[int], logs: Path, budget: Budget) -> list[dict[str, Any]]:
    """The tutorial recipe (both wrappers) and ours at its budget, per seed."""
    import numpy as np
    import torch

    from benchmarks.learning.games_tutorial import (
        TUTORIAL_EVAL_GAMES,
        TUTORIAL_STEPS,
        eval_tutorial_recipe,
        train_tutorial_recipe,
    )
    from sbagents.games.matches import match_summary, play_games
    from sbagents.games.players import ModelPlayer
    from sbagents.games.selfplay import make_selfplay_env

    game = GAMES[name]
    torch.set_num_threads(1)
    rows = []
    for seed in seeds:
        for variant in ("fixed", "original"):
            start = time.perf_counter()
            steps = budget.steps or TUTORIAL_STEPS
            model = train_tutorial_recipe(game.env, steps, seed, variant=variant)
            seconds = time.perf_counter() - start
            vs = {}
            for opponent in game.opponents:
                env = make_selfplay_env(game.env, opponent=opponent)
                result = play_games(env, ModelPlayer(model, True, rng=np.random.default_rng(seed)),
                                    budget.games or game.n_games, seed=EVAL_SEED)
                vs[opponent] = match_row(match_summary(result, game.stem, "tutorial", opponent))
            own = eval_tutorial_recipe(model, game.env, budget.games or TUTORIAL_EVAL_GAMES)
            rows.append({"who": f"tutorial ({variant})", "seed": seed, "n_timesteps": steps,
                         "train_s": round(seconds, 1), "tutorial_winrate": own["winrate"], "vs": vs})
            print(json.dumps(rows[-1]), flush=True)
        row = train_ours(game, seed, logs / f"{name}_tutorial_budget", budget, TUTORIAL_STEPS)
        rows.append({"who": "sbagents", **row})
        print(json.dumps(rows[-1]), flush=True)
    return rows


def _rate(vs: dict[str, Any], opponent: str, key: str) -> str:
    return f"{100 * vs[opponent][key]:.1f}%"


def game_markdown(name: str, result: dict[str, Any]) -> str:
    """A game's section of BENCHMARKS.md."""
    game = GAMES[name]
    lines = [f"## {game.title}: self-play MaskablePPO", "",
             f"`python -m sbagents.train --algo ppo_mask --env {game.env} --seed S` (shipped config), then "
             f"`python -m sbagents.evaluate --algo ppo_mask --env {game.env} --opponent O -n {game.n_games} --seed "
             f"{EVAL_SEED} --json` on the final model, seats alternating. Command: `{result['command']}`.", ""]
    poker = name == "holdem"
    cols = [f"vs {o}: {'chips/hand (big blinds) [95% CI]' if poker else 'win / draw / loss'}"
            for o in game.opponents]
    bar, met = BARS[name]
    lines += [f"Bar: {bar}.", "",
              "| seed | timesteps | train s | " + " | ".join(cols) + " | illegal moves | load | bar met |",
              "|---:|---:|---:|" + "---|" * len(cols) + "---:|---:|---|"]
    for row in result["runs"]:
        cells = []
        for o in game.opponents:
            vs = row["vs"][o]
            if poker:
                lo, hi = vs["reward_ci95"]
                cells.append(f"{vs['mean_reward']:+.3f} [{lo:+.3f}, {hi:+.3f}]")
            else:
                cells.append(" / ".join(_rate(row["vs"], o, k) for k in ("win_rate", "draw_rate", "loss_rate")))
        illegal = sum(v["illegal_moves"] for v in row["vs"].values())
        lines.append(f"| {row['seed']} | {row['n_timesteps']:,} | {row['train_s']:.0f} | " + " | ".join(cells)
                     + f" | {illegal} | {row['load']} | {'yes' if met(row) else 'no'} |")
    rows: list[StatsRow] = [(f"vs {o}", label, result["stats"][o], fmt)
                            for o in game.opponents for label, _, fmt in [_stats_metric(name, o)]]
    lines += ["", *grouped_stats_table("opponent", rows)]
    if result.get("elo_plot"):
        lines += ["", f"Ratings of seed 0's snapshots during training: `{result['elo_plot']}` (`elo.csv` beside it)."]
    return "\n".join(lines)


def tutorial_markdown(result: dict[str, Any]) -> str:
    """The side-by-side section (``result["shipped"]``: the game benchmarks' rows at the shipped budget)."""
    lines = ["## Turn-based games: PettingZoo's SB3 tutorial recipe vs sbagents", "",
             "PettingZoo's tutorial (`tutorials/SB3/connect_four/sb3_connect_four_action_mask.py`) rebuilt in "
             "`benchmarks/learning/games_tutorial.py`: MaskablePPO with sb3-contrib's defaults, one env, 20,480 steps, "
             "one policy through a single-agent wrapper of the AEC game. `fixed` is upstream's wrapper since May 2024 "
             "(the reward of the agent that moved); `original` the July 2023 one (the reward of the agent to move "
             "next: a win is scored -1). sbagents: the shipped config at the tutorial's 20,480 steps and at its own "
             "budget. Every row is evaluated by the same matches (final model, greedy, seats alternating, "
             f"{GAMES['connect4'].n_games} games per opponent, seed {EVAL_SEED}); `tutorial metric` is the "
             f"tutorial's own evaluation (100 games, the model always second, wins over decisive games). Command: "
             f"`{result['command']}`.", ""]
    for name in TUTORIAL_GAMES:
        game = GAMES[name]
        rows = [*result["games"][name], *({"who": "sbagents (shipped budget)", **r}
                                          for r in result["shipped"].get(name, []))]
        cols = [f"vs {o}: win / draw / loss" for o in game.opponents]
        lines += [f"### {game.title}", "", "| recipe | seed | timesteps | train s | " + " | ".join(cols)
                  + " | tutorial metric |", "|---|---:|---:|---:|" + "---|" * len(cols) + "---:|"]
        for row in rows:
            cells = [" / ".join(_rate(row["vs"], o, k) for k in ("win_rate", "draw_rate", "loss_rate"))
                     for o in game.opponents]
            metric = f"{row['tutorial_winrate']:.2f}" if "tutorial_winrate" in row else ""
            lines.append(f"| {row['who']} | {row['seed']} | {row['n_timesteps']:,} | {row['train_s']:.0f} | "
                         + " | ".join(cells) + f" | {metric} |")
        lines.append("")
    stats_rows: list[StatsRow] = [(f"{GAMES[name].title}: {who}", f"{label} vs {o}", stats, fmt)
                                  for name, by_who in result["stats"].items() for who, by_opponent in by_who.items()
                                  for o, stats in by_opponent.items() for label, _, fmt in [_stats_metric(name, o)]]
    return "\n".join([*lines, *grouped_stats_table("recipe", stats_rows)]).rstrip()


def _stats_metric(name: str, opponent: str) -> tuple[str, str, str]:
    """The over-seeds metric of a match: label, key of the match row and number format (chips per hand for poker,
    draw % against tic-tac-toe's minimax, win % otherwise)."""
    if name == "holdem":
        return "chips/hand (big blinds)", "mean_reward", ".3f"
    if opponent == "minimax":
        return "draw %", "draw_rate", ".1f"
    return "win %", "win_rate", ".1f"


def _match_value(name: str, opponent: str, vs: dict[str, Any]) -> float:
    _, key, _ = _stats_metric(name, opponent)
    return float(vs[opponent][key]) * (1 if key == "mean_reward" else 100)


def add_game_stats(name: str, result: dict[str, Any]) -> dict[str, Any]:
    """``result`` with ``stats[opponent]``: chips per hand (hold'em), draw % (minimax) or win % over the seeds."""
    stats = {o: stats_of([_match_value(name, o, r["vs"]) for r in result["runs"]]) for o in GAMES[name].opponents}
    return {**result, "stats": stats}


def add_tutorial_stats(result: dict[str, Any]) -> dict[str, Any]:
    """``result`` with ``stats[game][recipe][opponent]``: the game section's metric over the seeds of each recipe."""
    stats: dict[str, Any] = {}
    for name in TUTORIAL_GAMES:
        rows = [*result["games"][name], *({"who": "sbagents (shipped budget)", **r}
                                          for r in result["shipped"].get(name, []))]
        stats[name] = {who: {o: stats_of([_match_value(name, o, r["vs"]) for r in rows if r["who"] == who])
                             for o in GAMES[name].opponents}
                       for who in dict.fromkeys(r["who"] for r in rows)}
    return {**result, "stats": stats}


def build_parser(task: str) -> argparse.ArgumentParser:
    """The options of ``games-<task>``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run games-{task}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    if task != "tutorial":
        parser.add_argument("--add", action="store_true",
                            help="keep the saved runs of other seeds (from --stored; one command per seed)")
    parser.add_argument("--stored", default=None,
                        help="saved results: the runs --add keeps, or (tutorial) the game benchmarks' results "
                             "folder whose shipped-budget rows are shown (default: benchmarks/results)")
    parser.add_argument("--smoke", action="store_true",
                        help=f"{SMOKE_STEPS} training steps, {SMOKE_GAMES} games per match, no rating plot kept "
                             "(checks the benchmark; use with run --results and --output '')")
    return parser


def _command(task: str, argv: Sequence[str]) -> str:
    kept = [a for i, a in enumerate(argv) if "--stored" not in {a, argv[i - 1] if i else ""}]
    return shlex.join(["python", "-m", "benchmarks", "run", f"games-{task}", *recorded_argv(kept)])


def run_game(name: str, argv: Sequence[str]) -> dict[str, Any]:
    """Train and evaluate ``name`` on every seed; with ``--add``, beside the stored runs of other seeds."""
    args = build_parser(name).parse_args(list(argv))
    budget = SMOKE if args.smoke else Budget()
    with tempfile.TemporaryDirectory() as tmp:
        runs = [train_ours(GAMES[name], seed, Path(tmp) / f"{name}_{seed}", budget) for seed in args.seeds]
    for row in runs:
        print(json.dumps(row), flush=True)
    stored = Path(args.stored or RESULTS_DIR / f"games_{name}.json")
    saved = load_results(stored) if args.add and stored.exists() else {}
    kept = [row for row in saved.get("runs", []) if row["seed"] not in set(args.seeds)]
    merged = sorted([*kept, *runs], key=lambda row: row["seed"])
    elo = f"benchmarks/results/games_{GAMES[name].stem}_elo.png"
    result = {"command": _command(name, argv), "seeds": [row["seed"] for row in merged], "runs": merged,
              "elo_plot": elo if (RESULTS_DIR.parent.parent / elo).exists() and budget.keep_elo else None}
    return add_game_stats(name, result)


def run_tutorial(argv: Sequence[str]) -> dict[str, Any]:
    """The tutorial recipe and ours at its budget on every seed, beside the saved rows at the shipped budget."""
    args = build_parser("tutorial").parse_args(list(argv))
    budget = SMOKE if args.smoke else Budget()
    with tempfile.TemporaryDirectory() as tmp:
        games = {n: tutorial_rows(n, args.seeds, Path(tmp), budget) for n in TUTORIAL_GAMES}
    folder = Path(args.stored) if args.stored else RESULTS_DIR
    shipped = {n: load_results(folder / f"games_{n}.json")["runs"] for n in TUTORIAL_GAMES
               if (folder / f"games_{n}.json").exists()}
    return add_tutorial_stats({"command": _command("tutorial", argv), "seeds": args.seeds, "games": games,
                               "shipped": shipped})


def _game_benchmark(name: str) -> Benchmark:
    game = GAMES[name]
    return Benchmark(name=f"games-{name}", kind="learning", results=f"games_{name}.json",
                     summary=f"{game.title}: self-play MaskablePPO (shipped config) against fixed opponents",
                     run=partial(run_game, name), render=partial(game_markdown, name))


BENCHMARKS = (
    *(_game_benchmark(name) for name in ("connect4", "tictactoe", "holdem")),
    Benchmark(name="games-tutorial", kind="learning", results="games_tutorial.json",
              summary="PettingZoo's SB3 tutorial recipe vs sbagents on connect four and tic-tac-toe",
              run=run_tutorial, render=tutorial_markdown),
)
