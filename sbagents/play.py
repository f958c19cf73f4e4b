"""``python -m sbagents.play``: play a turn-based game (connect four, tic-tac-toe, texas hold'em, any masked
PettingZoo AEC game) against a trained agent in the terminal.

Parses the flags, loads the run and plays the games with :func:`sbagents.games.terminal.play_game`. Enter ``q``
(or end the input) to stop; the session ends with the tally of your wins, draws and losses.
"""

from __future__ import annotations

import sys

import numpy as np

from sbagents.cli_common import ArgumentParser, add_run_arguments, run, run_ref
from sbagents.core.env_kinds import GAME
from sbagents.errors import UsageError

#: ``--seat`` choices (default: alternate between games, starting first).
SEATS = ("first", "second", "random")
#: Games (poker: hands) per session when ``--games`` is not given.
DEFAULT_GAMES, DEFAULT_HANDS = 1, 10


def build_parser() -> ArgumentParser:
    """The ``play`` argument parser."""
    p = ArgumentParser(prog="python -m sbagents.play",
                       description="Play a turn-based game against a trained agent in the terminal.")
    add_run_arguments(p)
    p.add_argument("--seat", choices=SEATS, default=None,
                   help="your seat: first, second or random (default: alternate between games, starting first)")
    p.add_argument("--games", type=int, default=None,
                   help=f"games to play (default {DEFAULT_GAMES}; poker: hands, default {DEFAULT_HANDS})")
    p.add_argument("--seed", type=int, default=None, help="seed of the deals, random seats and sampled moves")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--deterministic", dest="deterministic", action="store_true", default=None,
                       help="the agent plays greedily (the default, unless the run's config sets "
                            "deterministic_eval: false)")
    group.add_argument("--stochastic", dest="deterministic", action="store_false",
                       help="the agent samples its moves from its policy")
    return p


def seat_index(seat: str | None, game: int, n_seats: int, rng: np.random.Generator) -> int:
    """The human's seat index in game number ``game`` (0-based) of ``--seat``."""
    if seat == "first":
        return 0
    if seat == "second":
        return 1
    if seat == "random":
        return int(rng.integers(n_seats))
    return game % n_seats


def ask(prompt: str) -> str:
    """Read the human's entry; piped input is echoed so the transcript reads like a session."""
    text = input(prompt)
    if not sys.stdin.isatty():
        print(text)
    return text


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv``, load the run, play the games, print each result and the tally."""
    args = build_parser().parse_args(argv)
    if args.games is not None and args.games < 1:
        raise UsageError(f"--games must be >= 1, got {args.games}")
    ref = run_ref(args)
    env_ref = ref.env_ref()
    if env_ref.kind is not GAME:
        raise UsageError(f"{env_ref.env_id} is not a turn-based game; play needs a PettingZoo AEC game with action "
                         "masks (e.g. pettingzoo.classic.connect_four_v3); use evaluate for other envs")
    import torch

    from sbagents.core.run_dir import load_run
    from sbagents.games.aec import game_name, make_game
    from sbagents.games.players import ModelPlayer
    from sbagents.games.selfplay import SELFPLAY_KWARGS
    from sbagents.games.terminal import (
        QuitSession,
        chips_per_point,
        game_kind,
        outcome_line,
        play_game,
        tally_line,
    )

    torch.set_num_threads(1)
    if args.seed is not None:
        torch.manual_seed(args.seed)
    loaded = load_run(ref)
    exp = loaded.experiment
    env = make_game(env_ref.source, env_ref.modules,
                    **{k: v for k, v in exp.env_kwargs.items() if k not in SELFPLAY_KWARGS})
    game = game_name(env_ref.source)
    poker = game_kind(game) == "texas_holdem"
    deterministic = exp.deterministic_eval if args.deterministic is None else args.deterministic
    agent = ModelPlayer(loaded.model, deterministic=deterministic)
    n_games = args.games or (DEFAULT_HANDS if poker else DEFAULT_GAMES)
    seats = list(env.possible_agents)
    rng = np.random.default_rng(args.seed)
    unit = "hand" if poker else "game"
    print(f"{game}: you against {loaded.model_path} ({'greedy' if deterministic else 'sampled'} moves)")
    per_point = chips_per_point(game, env)  # poker: the big blind (rewards are in big blinds)
    results: list[float] = []
    try:
        for number in range(n_games):
            human = seats[seat_index(args.seat, number, len(seats), rng)]
            print(f"\n{unit} {number + 1} of {n_games}: you are {human} (seat {seats.index(human) + 1} of "
                  f"{len(seats)})")
            returns = play_game(env, game, human, agent, ask, print, seed=args.seed if number == 0 else None)
            results.append(returns[human])
            print(outcome_line(returns[human], per_point))
    except QuitSession:
        print("you quit")
    except EOFError:
        print("\nend of input")
    except KeyboardInterrupt:
        print(f"\n{tally_line(results, per_point)}")
        raise
    finally:
        env.close()
    print(tally_line(results, per_point))
    return 0


if __name__ == "__main__":
    run("python -m sbagents.play", main)
