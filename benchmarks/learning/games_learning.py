"""Turn-based games: self-play MaskablePPO through the CLI with the shipped configs, measured against fixed opponents,
and PettingZoo's own SB3 tutorial recipe side by side.

Per game and seed: ``python -m sbagents.train --algo ppo_mask --env GAME --seed S`` (shipped ``zoo_configs/
ppo_mask.yml`` entry), then ``python -m sbagents.evaluate --opponent O -n GAMES --seed 10000 --json`` on the final
model for each opponent (seats alternate). Bars (issue 16): tic-tac-toe no loss in 1,000 games against random and
>= 95% draws against minimax; connect four >= 98% wins against random and >= 60% against the heuristic within 15
minutes of training; texas hold'em mean chips per hand against random > 0 with its 95% interval above zero.

``tutorial``: PettingZoo's tutorial recipe (:mod:`benchmarks.games_tutorial`, both the upstream and the original
2023 wrapper) at its 20,480 steps, ours at the same budget (``-n 20480``), and ours at the shipped budget (the rows
of the game tasks run in the same command, else the saved ones), all evaluated by the same matches.

    python -m benchmarks.games_learning connect4 tictactoe holdem tutorial --seeds 0 1 2
    python -m benchmarks.games_learning connect4 --seeds 1 --add   # a seed beside the saved ones
    python -m benchmarks.games_learning tutorial --render-only     # redraw a section from the saved results
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from benchmarks.report import write_section

RESULTS = Path(__file__).resolve().parent / "results"
EVAL_SEED = 10_000
#: ``--smoke``: games per match and training budget (a check that the script runs end to end; 0: off).
SMOKE_GAMES = 0
SMOKE_STEPS = 2048


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


def evaluate_run(game: Game, logs: Path) -> dict[str, Any]:
    """The latest run in ``logs`` against each of the game's opponents."""
    out = {}
    for opponent in game.opponents:
        done = cli("evaluate", "--algo", "ppo_mask", "--env", game.env, "-f", str(logs), "--opponent", opponent,
                   "-n", str(SMOKE_GAMES or game.n_games), "--seed", str(EVAL_SEED), "--json")
        out[opponent] = match_row(json.loads(done.stdout.splitlines()[-1]))
    return out


def train_ours(game: Game, seed: int, logs: Path, budget: int | None = None) -> dict[str, Any]:
    """Train with the shipped config (``-n budget`` if given) and evaluate; one row."""
    budget = SMOKE_STEPS if SMOKE_GAMES else budget
    extra = ["-n", str(budget)] if budget is not None else []
    cli("train", "--algo", "ppo_mask", "--env", game.env, "--seed", str(seed), "-f", str(logs), *extra,
        "--final-eval-episodes", "0")
    run_dir = sorted((logs / "ppo_mask").iterdir(), key=lambda p: p.stat().st_mtime)[-1]
    summary = json.loads((run_dir / "summary.json").read_text())
    row = {"seed": seed, "n_timesteps": summary["n_timesteps"], "train_s": summary["train_seconds"],
           "load": round(os.getloadavg()[0], 2), "vs": evaluate_run(game, logs)}
    if seed == 0 and budget is None and not SMOKE_GAMES and (run_dir / "elo.png").exists():
        shutil.copyfile(run_dir / "elo.png", RESULTS / f"games_{game.stem}_elo.png")
        shutil.copyfile(run_dir / "elo.csv", RESULTS / f"games_{game.stem}_elo.csv")
    return row


def tutorial_rows(name: str, seeds: list[int], logs: Path) -> list[dict[str, Any]]:
    """The tutorial recipe (both wrappers) and ours at its budget, per seed."""
    import numpy as np
    import torch

    from benchmarks.games_tutorial import TUTORIAL_STEPS, eval_tutorial_recipe, train_tutorial_recipe
    from sbagents.games.matches import match_summary, play_games
    from sbagents.games.players import ModelPlayer
    from sbagents.games.selfplay import make_selfplay_env

    game = GAMES[name]
    torch.set_num_threads(1)
    rows = []
    for seed in seeds:
        for variant in ("fixed", "original"):
            start = time.perf_counter()
            steps = SMOKE_STEPS if SMOKE_GAMES else TUTORIAL_STEPS
            model = train_tutorial_recipe(game.env, steps, seed, variant=variant)
            seconds = time.perf_counter() - start
            vs = {}
            for opponent in game.opponents:
                env = make_selfplay_env(game.env, opponent=opponent)
                result = play_games(env, ModelPlayer(model, True, rng=np.random.default_rng(seed)),
                                    SMOKE_GAMES or game.n_games, seed=EVAL_SEED)
                vs[opponent] = match_row(match_summary(result, game.stem, "tutorial", opponent))
            own = eval_tutorial_recipe(model, game.env)
            rows.append({"who": f"tutorial ({variant})", "seed": seed, "n_timesteps": steps,
                         "train_s": round(seconds, 1), "tutorial_winrate": own["winrate"], "vs": vs})
            print(json.dumps(rows[-1]), flush=True)
        row = train_ours(game, seed, logs / f"{name}_tutorial_budget", TUTORIAL_STEPS)
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
             f"{EVAL_SEED} --json` on the final model, seats alternating. Command: `python -m "
             f"benchmarks.games_learning {name} --seeds {' '.join(str(s) for s in result['seeds'])}`.", ""]
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
    if (RESULTS / f"games_{game.stem}_elo.png").exists():
        lines += ["", f"Ratings of seed 0's snapshots during training: `benchmarks/results/games_{game.stem}_elo.png`"
                  f" (`elo.csv` beside it)."]
    return "\n".join(lines)


def tutorial_markdown(result: dict[str, Any], shipped: dict[str, Any]) -> str:
    """The side-by-side section."""
    lines = ["## Turn-based games: PettingZoo's SB3 tutorial recipe vs sbagents", "",
             "PettingZoo's tutorial (`tutorials/SB3/connect_four/sb3_connect_four_action_mask.py`) rebuilt in "
             "`benchmarks/games_tutorial.py`: MaskablePPO with sb3-contrib's defaults, one env, 20,480 steps, one "
             "policy through a single-agent wrapper of the AEC game. `fixed` is upstream's wrapper since May 2024 "
             "(the reward of the agent that moved); `original` the July 2023 one (the reward of the agent to move "
             "next: a win is scored -1). sbagents: the shipped config at the tutorial's 20,480 steps and at its own "
             "budget. Every row is evaluated by the same matches (final model, greedy, seats alternating, "
             f"{GAMES['connect4'].n_games} games per opponent, seed {EVAL_SEED}); `tutorial metric` is the "
             "tutorial's own evaluation (100 games, the model always second, wins over decisive games). Command: "
             f"`python -m benchmarks.games_learning tutorial --seeds {' '.join(str(s) for s in result['seeds'])}`.",
             ""]
    for name in TUTORIAL_GAMES:
        game = GAMES[name]
        rows = [*result["games"][name], *({"who": "sbagents (shipped budget)", **r}
                                          for r in shipped.get(name, {}).get("runs", []))]
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
    return "\n".join(lines).rstrip()


def main(argv: list[str] | None = None) -> int:
    """Run the named tasks; write ``benchmarks/results/games_*.json`` and their BENCHMARKS.md sections."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.games_learning", description=__doc__)
    parser.add_argument("tasks", nargs="+", choices=[*GAMES, "tutorial"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--output", default="BENCHMARKS.md", help="Markdown file to update ('' = none)")
    parser.add_argument("--add", action="store_true",
                        help="keep the saved runs of other seeds (run seeds as separate commands, then --render-only)")
    parser.add_argument("--render-only", action="store_true",
                        help="rewrite the tasks' sections from the saved results (no training)")
    parser.add_argument("--smoke", action="store_true",
                        help=f"{SMOKE_STEPS} training steps, 20 games per match, results into a temporary folder "
                             "(checks the script; use with --output '')")
    args = parser.parse_args(argv)
    if args.smoke:
        global RESULTS, SMOKE_GAMES
        RESULTS, SMOKE_GAMES = Path(tempfile.mkdtemp(prefix="games_smoke_")), 20
    RESULTS.mkdir(exist_ok=True)
    if args.render_only:
        for name in args.tasks:
            text = (tutorial_markdown(_saved("tutorial"), {n: _saved(n) for n in TUTORIAL_GAMES}) if name == "tutorial"
                    else game_markdown(name, _saved(name)))
            print(text)
            if args.output:
                write_section(args.output, text, f"games-{name}")
        return 0
    done: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.tasks:
            if name == "tutorial":
                continue
            runs = [train_ours(GAMES[name], seed, Path(tmp) / f"{name}_{seed}") for seed in args.seeds]
            for row in runs:
                print(json.dumps(row), flush=True)
            done[name] = _store(name, runs, args.add)
            if args.output:
                write_section(args.output, game_markdown(name, done[name]), f"games-{name}")
        if "tutorial" in args.tasks:
            result = {"seeds": args.seeds,
                      "games": {n: tutorial_rows(n, args.seeds, Path(tmp)) for n in TUTORIAL_GAMES}}
            (RESULTS / "games_tutorial.json").write_text(json.dumps(result, indent=1) + "\n")
            shipped = {n: done.get(n) or _saved(n) for n in TUTORIAL_GAMES}
            if args.output:
                write_section(args.output, tutorial_markdown(result, shipped), "games-tutorial")
    return 0


def _store(name: str, runs: list[dict[str, Any]], add: bool) -> dict[str, Any]:
    """Write ``games_<name>.json`` (with ``add``: beside the saved runs of other seeds; a lock keeps concurrent
    commands for different seeds from losing each other's runs) and return what it holds."""
    import fcntl

    with (RESULTS / ".games.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        seeds = {row["seed"] for row in runs}
        kept = [row for row in _saved(name).get("runs", []) if row["seed"] not in seeds] if add else []
        merged = sorted([*kept, *runs], key=lambda row: row["seed"])
        result = {"seeds": [row["seed"] for row in merged], "runs": merged}
        (RESULTS / f"games_{name}.json").write_text(json.dumps(result, indent=1) + "\n")
    return result


def _saved(name: str) -> dict[str, Any]:
    path = RESULTS / f"games_{name}.json"
    return json.loads(path.read_text()) if path.exists() else {}


if __name__ == "__main__":
    raise SystemExit(main())
