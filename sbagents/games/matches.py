"""Matches between a player and an opponent: win/draw/loss rates per seat, chips per game, illegal moves.

:func:`play_games` plays ``n_games`` with the player's seat alternating (a game that ends before the player's seat
moves, such as a poker hand folded at once, still counts) with the episode runner
(:func:`sbagents.callbacks.episodes.play_env_episodes`: one record per game, its outcome in ``record.game``);
:func:`match_summary` is the ``evaluate --json`` contract of games (docs/architecture.md): the generic evaluation
keys plus ``win_rate``, ``draw_rate``, ``loss_rate``, ``mean_reward`` with its 95% interval, ``per_seat`` and
``illegal_moves``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sbagents.callbacks.episodes import EpisodeRecord, game_rates, play_env_episodes, stateless, summarize_records
from sbagents.games.players import Player
from sbagents.games.selfplay import SelfPlayEnv


@dataclass
class MatchResult:
    """The games of one match (records with their :class:`~sbagents.callbacks.episodes.GameOutcome`) and the
    illegal moves of each side."""

    seats: list[str]
    games: list[EpisodeRecord] = field(default_factory=list)
    illegal_moves: int = 0
    opponent_illegal_moves: int = 0

    def score(self) -> float:
        """The player's Elo score: (wins + draws / 2) / games."""
        rewards = np.array([g.ret for g in self.games])
        return float(np.mean((rewards > 0) + 0.5 * (rewards == 0))) if len(rewards) else 0.5


def play_games(env: SelfPlayEnv, player: Player, n_games: int, seed: int | None = 0) -> MatchResult:
    """Play ``n_games`` of ``env``'s game: ``player`` in the learner's seat (alternating), ``env``'s opponent in
    the others.

    :param env: a :class:`SelfPlayEnv` with the opponent fixed (it is reset with ``seed`` first).
    """
    opp_before = env.opponent_illegal_moves
    games = play_env_episodes(env, stateless(lambda obs: player(obs, env.action_masks())), n_games, seed)
    return MatchResult(list(env.seats), games, sum(g.game.illegal_moves for g in games if g.game is not None),
                       env.opponent_illegal_moves - opp_before)


def match_summary(result: MatchResult, env_id: str, algo: str, opponent: str) -> dict[str, Any]:
    """The evaluation summary of a match (the keys of :func:`sbagents.callbacks.episodes.summarize_records` too:
    ``mean_return`` is the mean reward per game, ``success_rate`` the win rate)."""
    games = result.games
    rates = game_rates(games)
    rewards = np.array([g.ret for g in games], dtype=float)
    half = 1.96 * float(np.std(rewards, ddof=1)) / np.sqrt(len(rewards)) if len(rewards) > 1 else float("nan")
    mean = rates["mean_reward"]
    per_seat = {seat: game_rates([g for g in games if g.game is not None and g.game.seat == i])
                for i, seat in enumerate(result.seats)}
    generic = summarize_records(games) if games else {"n_episodes": 0, "mean_return": None, "std_return": None,
                                                      "mean_length": None}
    return {
        "env": env_id, "algo": algo, "opponent": opponent, "n_episodes": generic["n_episodes"],
        "mean_return": generic["mean_return"], "std_return": generic["std_return"],
        "mean_length": generic["mean_length"], "success_rate": rates["win_rate"], "metrics": {},
        **rates, "reward_ci95": [mean - half, mean + half] if mean is not None else None,
        "per_seat": per_seat, "illegal_moves": result.illegal_moves,
        "opponent_illegal_moves": result.opponent_illegal_moves,
    }
