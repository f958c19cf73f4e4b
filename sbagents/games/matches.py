"""Matches between a player and an opponent: win/draw/loss rates per seat, chips per game, illegal moves.

:func:`play_games` plays ``n_games`` with the player's seat alternating (a game that ends before the player's seat
moves, such as a poker hand folded at once, still counts); :func:`match_summary` is the ``evaluate --json``
contract of games (docs/architecture.md): the generic evaluation keys plus ``win_rate``, ``draw_rate``,
``loss_rate``, ``mean_reward`` with its 95% interval, ``per_seat`` and ``illegal_moves``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sbagents.games.players import Player
from sbagents.games.selfplay import ILLEGAL_KEY, RETURN_KEY, SEAT_KEY, UNPLAYED_KEY, SelfPlayEnv


@dataclass
class GameRecord:
    """One game from the player's side: its seat index, return (its reward sum), and moves."""

    seat: int
    reward: float
    moves: int


@dataclass
class MatchResult:
    """The games of one match and the illegal moves of each side."""

    seats: list[str]
    games: list[GameRecord] = field(default_factory=list)
    illegal_moves: int = 0
    opponent_illegal_moves: int = 0

    def score(self) -> float:
        """The player's Elo score: (wins + draws / 2) / games."""
        rewards = np.array([g.reward for g in self.games])
        return float(np.mean((rewards > 0) + 0.5 * (rewards == 0))) if len(rewards) else 0.5


def play_games(env: SelfPlayEnv, player: Player, n_games: int, seed: int | None = 0) -> MatchResult:
    """Play ``n_games`` of ``env``'s game: ``player`` in the learner's seat (alternating), ``env``'s opponent in
    the others.

    :param env: a :class:`SelfPlayEnv` with the opponent fixed (it is reset with ``seed`` first).
    """
    result = MatchResult(list(env.seats))
    illegal_before, opp_before = env.illegal_moves, env.opponent_illegal_moves
    obs, info = env.reset(seed=seed)
    while True:
        result.games += [GameRecord(seat, reward, 0) for seat, reward in info[UNPLAYED_KEY]]
        if len(result.games) >= n_games:
            break
        moves, done = 0, False
        while not done:
            obs, _, terminated, truncated, step_info = env.step(player(obs, env.action_masks()))
            moves += 1
            done = terminated or truncated
        result.games.append(GameRecord(int(step_info[SEAT_KEY]), float(step_info[RETURN_KEY]), moves))
        assert step_info[ILLEGAL_KEY] in (0, 1)
        if len(result.games) >= n_games:
            break
        obs, info = env.reset()
    del result.games[n_games:]
    result.illegal_moves = env.illegal_moves - illegal_before
    result.opponent_illegal_moves = env.opponent_illegal_moves - opp_before
    return result


def _rates(rewards: np.ndarray) -> dict[str, Any]:
    n = len(rewards)
    if n == 0:
        return {"n_games": 0, "win_rate": None, "draw_rate": None, "loss_rate": None, "mean_reward": None}
    return {"n_games": n, "win_rate": float(np.mean(rewards > 0)), "draw_rate": float(np.mean(rewards == 0)),
            "loss_rate": float(np.mean(rewards < 0)), "mean_reward": float(np.mean(rewards))}


def match_summary(result: MatchResult, env_id: str, algo: str, opponent: str) -> dict[str, Any]:
    """The evaluation summary of a match (the keys of :func:`sbagents.pipeline.evaluation.summarize` too:
    ``mean_return`` is the mean reward per game, ``success_rate`` the win rate)."""
    rewards = np.array([g.reward for g in result.games], dtype=float)
    rates = _rates(rewards)
    half = 1.96 * float(np.std(rewards, ddof=1)) / np.sqrt(len(rewards)) if len(rewards) > 1 else float("nan")
    mean = rates["mean_reward"]
    per_seat = {seat: _rates(np.array([g.reward for g in result.games if g.seat == i], dtype=float))
                for i, seat in enumerate(result.seats)}
    return {
        "env": env_id, "algo": algo, "opponent": opponent, "n_episodes": len(rewards),
        "mean_return": mean, "std_return": float(np.std(rewards)) if len(rewards) else None,
        "mean_length": float(np.mean([g.moves for g in result.games])) if result.games else None,
        "success_rate": rates["win_rate"], "metrics": {},
        **rates, "reward_ci95": [mean - half, mean + half] if mean is not None else None,
        "per_seat": per_seat, "illegal_moves": result.illegal_moves,
        "opponent_illegal_moves": result.opponent_illegal_moves,
    }
