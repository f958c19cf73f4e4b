"""The built-in scripted opponents on the real PettingZoo envs: the board layouts they assume, the connect four
heuristic (win, block, centre; legal; beats random play) and tic-tac-toe minimax (perfect; never loses), and
:func:`builtin_for`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import pytest
from pettingzoo.classic import connect_four_v3, tictactoe_v3

from sbagents.games.builtin import (
    BUILTIN_OPPONENTS,
    C4_CENTRE_WEIGHTS,
    C4_LINES,
    builtin_for,
    connect_four_heuristic,
    connect_four_opportunist,
    tictactoe_minimax,
    tictactoe_opportunist,
)

Policy = Callable[[np.ndarray, np.ndarray], int]


def position(make_env: Callable[[], Any], moves: Sequence[int]) -> tuple[Any, str, np.ndarray, np.ndarray]:
    """A fresh env after ``moves``: (env, agent to move, its observation, its action mask)."""
    env = make_env()
    env.reset(seed=0)
    for move in moves:
        assert env.agents and not env.terminations[env.agent_selection], f"game over before move {move} of {moves}"
        env.step(move)
    agent = env.agent_selection
    seen = env.observe(agent)
    return env, agent, seen["observation"], seen["action_mask"]


def play(make_env: Callable[[], Any], players: Sequence[Policy]) -> tuple[list[float], list[int]]:
    """One game, ``players[i]`` seated as ``possible_agents[i]``; every action is checked against the mask.

    :return: each seat's total reward (summed from ``env.rewards`` after every step), and the moves played.
    """
    env = make_env()
    env.reset()
    seat = {agent: player for agent, player in zip(env.possible_agents, players, strict=True)}
    totals = dict.fromkeys(env.possible_agents, 0.0)
    moves: list[int] = []
    while env.agents:
        obs, _, term, trunc, _ = env.last()
        if term or trunc:
            env.step(None)
        else:
            action = seat[env.agent_selection](obs["observation"], obs["action_mask"])
            assert obs["action_mask"][action] == 1, f"illegal move {action} after {moves}"
            env.step(action)
            moves.append(action)
        for agent, reward in env.rewards.items():
            totals[agent] += reward
    return [totals[agent] for agent in env.possible_agents], moves


def scripted(fn: Callable[[np.ndarray, np.ndarray, np.random.Generator], int], seed: int) -> Policy:
    rng = np.random.default_rng(seed)
    return lambda obs, mask: fn(obs, mask, rng)


def uniform(seed: int) -> Policy:
    rng = np.random.default_rng(seed)
    return lambda obs, mask: int(rng.choice(np.flatnonzero(mask)))


def match(make_env: Callable[[], Any], hero: Policy, villain: Policy, games: int) -> list[float]:
    """The hero's result (+1, 0, -1) in each of ``games`` games, seats alternated."""
    results = []
    for game in range(games):
        players = (hero, villain) if game % 2 == 0 else (villain, hero)
        totals, _ = play(make_env, players)
        results.append(totals[game % 2])
        assert sum(totals) == 0
    return results


# --------------------------------------------------------------------------------------------------------------------
# Layouts of the real envs
# --------------------------------------------------------------------------------------------------------------------


def test_connect_four_layout() -> None:
    """Row 0 is the top: pieces land on the largest free row; channel 0 is the observer's, channel 1 the other's."""
    env, agent, obs, mask = position(connect_four_v3.env, [3])
    assert agent == "player_1" and obs.shape == (6, 7, 2) and mask.tolist() == [1] * 7
    assert obs[5, 3, 1] == 1 and obs.sum() == 1  # player_0's piece at the bottom, in the opponent channel
    env.step(3)
    seen = env.observe("player_0")["observation"]
    assert seen[5, 3, 0] == 1 and seen[4, 3, 1] == 1 and seen.sum() == 2
    _, _, obs, mask = position(connect_four_v3.env, [2] * 6)
    assert mask.tolist() == [1, 1, 0, 1, 1, 1, 1]  # a full column is masked
    assert obs[:, 2, 0].tolist() == [0, 1, 0, 1, 0, 1] and obs[:, 2, 1].tolist() == [1, 0, 1, 0, 1, 0]


def test_tictactoe_layout() -> None:
    """Action ``a`` is the square ``observation[a // 3, a % 3]``."""
    for action in range(9):
        env, agent, obs, mask = position(tictactoe_v3.env, [action])
        first, second = env.possible_agents  # "player_1", "player_2" in tic-tac-toe
        assert agent == second and obs.shape == (3, 3, 2)
        assert obs[action // 3, action % 3, 1] == 1 and obs.sum() == 1
        assert mask[action] == 0 and mask.sum() == 8
        assert env.observe(first)["observation"][action // 3, action % 3, 0] == 1


def test_c4_lines() -> None:
    assert C4_LINES.shape == (69, 4) and len({tuple(sorted(line)) for line in C4_LINES.tolist()}) == 69
    steps = {(b // 7 - a // 7, b % 7 - a % 7) for a, b, *_ in C4_LINES.tolist()}
    assert steps == {(0, 1), (1, 0), (1, 1), (1, -1)}


# --------------------------------------------------------------------------------------------------------------------
# Connect four heuristic
# --------------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("moves", "win"),
    [
        ([0, 6, 1, 6, 2, 5], 3),  # horizontal, bottom row 0 1 2 _
        ([0, 6, 0, 5, 0, 6], 0),  # vertical, column 0
        ([3, 4, 4, 5, 5, 6, 5, 6, 6, 0], 6),  # rising diagonal (5,3) (4,4) (3,5) _(2,6)
        ([3, 2, 2, 1, 1, 0, 1, 0, 0, 6], 0),  # falling diagonal (5,3) (4,2) (3,1) _(2,0)
        ([6, 0, 6, 1, 5, 2, 5], 3),  # player_1 to move: 0 1 2 _ on the bottom row is its own
    ],
)
def test_heuristic_takes_a_win(moves: list[int], win: int) -> None:
    env, agent, obs, mask = position(connect_four_v3.env, moves)
    for seed in range(5):
        assert connect_four_heuristic(obs, mask, np.random.default_rng(seed)) == win
    env.step(win)
    assert env.rewards[agent] == 1 and all(env.terminations.values())


@pytest.mark.parametrize(
    ("moves", "block"),
    [
        ([0, 6, 1, 6, 2], 3),  # player_1 must block 0 1 2 _ on the bottom row
        ([6, 0, 5, 0, 6, 0], 0),  # player_0 must block column 0
        ([3, 4, 4, 5, 5, 6, 5, 6, 6], 6),  # player_1 must block the rising diagonal at (2, 6)
    ],
)
def test_heuristic_blocks(moves: list[int], block: int) -> None:
    env, agent, obs, mask = position(connect_four_v3.env, moves)
    for seed in range(5):
        assert connect_four_heuristic(obs, mask, np.random.default_rng(seed)) == block
    env.step(block)  # the opponent no longer wins there: its threat square is now ours
    assert not any(env.terminations.values())


def test_heuristic_prefers_win_over_block() -> None:
    env, agent, obs, mask = position(connect_four_v3.env, [0, 6, 1, 6, 2, 6])  # both threaten: we at 3, they at 6
    assert {connect_four_heuristic(obs, mask, np.random.default_rng(seed)) for seed in range(20)} == {3}
    env.step(3)
    assert env.rewards[agent] == 1


def drop_wins(board: np.ndarray, column: int, side: int) -> bool:
    """Brute force: does dropping a piece of ``side`` in ``column`` complete one of the 69 lines?"""
    free = [row for row in range(6) if not board[row, column].any()]
    if not free:
        return False
    pieces = board[:, :, side].copy()
    pieces[max(free), column] = 1
    flat = pieces.reshape(42)
    return bool((flat[C4_LINES].sum(axis=1) == 4).any())


def test_heuristic_matches_brute_force_on_game_positions() -> None:
    """Over every position of many games, the choice is a win if any, else a block if any, else legal."""
    rng = np.random.default_rng(0)
    checked = wins = blocks = 0
    for game in range(60):
        greedy = game / 60  # from random play to heuristic self-play: varied, crowded and tactical boards
        env = connect_four_v3.env()
        env.reset()
        while env.agents:
            obs, _, term, trunc, _ = env.last()
            if term or trunc:
                env.step(None)
                continue
            board, mask = obs["observation"], obs["action_mask"]
            legal = np.flatnonzero(mask).tolist()
            choice = connect_four_heuristic(board, mask, rng)
            winning = [c for c in legal if drop_wins(board, c, 0)]
            blocking = [c for c in legal if drop_wins(board, c, 1)]
            assert choice in legal
            if winning:
                assert choice in winning
                wins += 1
            elif blocking:
                assert choice in blocking
                blocks += 1
            checked += 1
            env.step(choice if rng.random() < greedy else int(rng.choice(legal)))
    assert checked > 1000 and wins > 20 and blocks > 20


def test_heuristic_centre_preference_and_mask() -> None:
    empty = np.zeros((6, 7, 2), dtype=np.int8)
    rng = np.random.default_rng(0)
    counts = np.bincount([connect_four_heuristic(empty, np.ones(7, np.int8), rng) for _ in range(8000)], minlength=7)
    assert C4_CENTRE_WEIGHTS == (1, 2, 3, 4, 3, 2, 1)
    expected = np.array([1, 2, 3, 4, 3, 2, 1]) / 16
    assert np.abs(counts / 8000 - expected).max() < 0.02
    mask = np.array([1, 0, 0, 0, 0, 0, 1], dtype=np.int8)
    assert {connect_four_heuristic(empty, mask, rng) for _ in range(200)} == {0, 6}
    only = np.zeros(7, dtype=np.int8)
    only[4] = 1
    assert {connect_four_heuristic(empty, only, rng) for _ in range(50)} == {4}
    # a winning drop in a column the mask forbids is not taken
    _, _, obs, mask = position(connect_four_v3.env, [0, 6, 1, 6, 2, 5])
    mask = mask.copy()
    mask[3] = 0
    assert all(connect_four_heuristic(obs, mask, rng) != 3 for _ in range(50))
    with pytest.raises(ValueError, match="no column"):
        connect_four_heuristic(empty, np.zeros(7, np.int8), rng)


def test_heuristic_beats_random_and_never_plays_illegally() -> None:
    """200 games against a uniform random player, seats alternated; :func:`play` checks every move's legality."""
    results = match(connect_four_v3.env, scripted(connect_four_heuristic, 0), uniform(1), 200)
    assert np.mean(np.array(results) == 1) >= 0.9
    # heuristic against itself fills boards up (full columns, draws): still only legal moves
    for game in range(20):
        totals, moves = play(connect_four_v3.env, [scripted(connect_four_heuristic, 2 * game + s) for s in (0, 1)])
        assert len(moves) >= 7 and sum(totals) == 0


def test_opportunist_takes_wins_never_blocks_and_otherwise_plays_uniformly() -> None:
    _, _, obs, mask = position(connect_four_v3.env, [0, 6, 1, 6, 2, 5])  # a win at 3
    assert {connect_four_opportunist(obs, mask, np.random.default_rng(seed)) for seed in range(10)} == {3}
    _, _, obs, mask = position(connect_four_v3.env, [0, 6, 1, 6, 2])  # only the opponent threatens (at 3)
    picks = [connect_four_opportunist(obs, mask, np.random.default_rng(seed)) for seed in range(700)]
    counts = np.bincount(picks, minlength=7) / 700
    assert np.all(np.abs(counts - 1 / 7) < 0.05)  # no blocking, no centre preference
    results = match(connect_four_v3.env, scripted(connect_four_heuristic, 0), scripted(connect_four_opportunist, 1),
                    100)
    assert len(results) == 100  # play() checked every move's legality
    assert builtin_for("opportunist", "connect_four_v3") is connect_four_opportunist


# --------------------------------------------------------------------------------------------------------------------
# Tic-tac-toe minimax
# --------------------------------------------------------------------------------------------------------------------


def test_minimax_takes_a_win_fastest() -> None:
    # player_0 holds 0 and 1 and wins at 2; player_1 (3, 4) threatens 5; other moves would also win later
    env, agent, obs, mask = position(tictactoe_v3.env, [0, 3, 1, 4])
    assert {tictactoe_minimax(obs, mask, np.random.default_rng(seed)) for seed in range(20)} == {2}
    env.step(2)
    assert env.rewards == {"player_1": 1, "player_2": -1} and agent == "player_1"


@pytest.mark.parametrize(("moves", "block"), [([0, 4, 1], 2), ([4, 0, 2], 6), ([0, 4, 8, 2], 6)])
def test_minimax_blocks(moves: list[int], block: int) -> None:
    _, _, obs, mask = position(tictactoe_v3.env, moves)
    assert {tictactoe_minimax(obs, mask, np.random.default_rng(seed)) for seed in range(20)} == {block}


def test_minimax_self_play_always_draws() -> None:
    games = set()
    for game in range(50):
        totals, moves = play(tictactoe_v3.env, [scripted(tictactoe_minimax, 2 * game + s) for s in (0, 1)])
        assert totals == [0.0, 0.0] and len(moves) == 9
        games.add(tuple(moves))
    assert len(games) > 5  # random tie-breaking among optimal moves


def test_minimax_never_loses_to_random() -> None:
    results = match(tictactoe_v3.env, scripted(tictactoe_minimax, 0), uniform(1), 300)
    assert min(results) >= 0 and sum(r == 1 for r in results) > 150


@pytest.mark.parametrize("seat", [0, 1])
def test_minimax_never_loses_to_any_line(seat: int) -> None:
    """Exhaustive: every reply of the opponent at every turn, replayed on the real env; minimax never loses."""
    rng = np.random.default_rng(seat)
    leaves = 0

    def explore(moves: list[int]) -> None:
        nonlocal leaves
        env, agent, obs, mask = position(tictactoe_v3.env, moves)
        if all(env.terminations.values()):
            assert env.rewards[env.possible_agents[seat]] >= 0, moves  # the last step's rewards
            leaves += 1
            return
        if agent == env.possible_agents[seat]:
            action = tictactoe_minimax(obs, mask, rng)
            assert mask[action] == 1
            explore([*moves, action])
        else:
            for action in np.flatnonzero(mask).tolist():
                explore([*moves, action])

    explore([])
    assert leaves > 50


def test_minimax_respects_the_mask() -> None:
    empty = np.zeros((3, 3, 2), dtype=np.int8)
    rng = np.random.default_rng(0)
    assert {tictactoe_minimax(empty, np.ones(9, np.int8), rng) for _ in range(200)} == set(range(9))  # all draw
    only = np.zeros(9, dtype=np.int8)
    only[7] = 1
    assert tictactoe_minimax(empty, only, rng) == 7
    _, _, obs, mask = position(tictactoe_v3.env, [0, 3, 1, 4])
    mask = mask.copy()
    mask[2] = 0  # the win is masked away: still a legal move
    assert all(mask[tictactoe_minimax(obs, mask, rng)] == 1 for _ in range(20))
    with pytest.raises(ValueError, match="no square"):
        tictactoe_minimax(empty, np.zeros(9, np.int8), rng)


def test_tictactoe_opportunist_takes_wins_never_blocks_and_otherwise_plays_uniformly() -> None:
    _, _, obs, mask = position(tictactoe_v3.env, [0, 3, 1, 4])  # player_0 wins at 2 (player_1 threatens 5)
    assert {tictactoe_opportunist(obs, mask, np.random.default_rng(seed)) for seed in range(20)} == {2}
    _, _, obs, mask = position(tictactoe_v3.env, [0, 4, 8, 3])  # only the opponent threatens (at 5)
    picks = [tictactoe_opportunist(obs, mask, np.random.default_rng(seed)) for seed in range(1000)]
    assert set(picks) == {1, 2, 5, 6, 7}  # legal squares only
    assert np.all(np.abs(np.bincount(picks, minlength=9)[[1, 2, 5, 6, 7]] / 1000 - 1 / 5) < 0.05)  # no blocking
    results = match(tictactoe_v3.env, scripted(tictactoe_minimax, 0), scripted(tictactoe_opportunist, 1), 100)
    assert -1 not in results and len(results) == 100  # minimax never loses; play() checked every move
    assert builtin_for("opportunist", "tictactoe_v3") is tictactoe_opportunist
    with pytest.raises(ValueError, match="no square"):
        tictactoe_opportunist(obs, np.zeros(9, np.int8), np.random.default_rng(0))


# --------------------------------------------------------------------------------------------------------------------
# Lookup
# --------------------------------------------------------------------------------------------------------------------


def test_builtin_for() -> None:
    assert set(BUILTIN_OPPONENTS) == {"heuristic", "opportunist", "minimax"}
    assert BUILTIN_OPPONENTS["heuristic"] == {"connect_four_v3": connect_four_heuristic}
    assert BUILTIN_OPPONENTS["minimax"] == {"tictactoe_v3": tictactoe_minimax}
    assert builtin_for("heuristic", "connect_four_v3") is connect_four_heuristic
    assert builtin_for("heuristic", "connect_four_v4") is connect_four_heuristic
    assert builtin_for("heuristic", "connect_four_v12") is connect_four_heuristic
    assert builtin_for("heuristic", "pettingzoo.classic.connect_four_v3") is connect_four_heuristic
    assert builtin_for("minimax", "tictactoe_v3") is tictactoe_minimax
    assert builtin_for("minimax", "tictactoe_v4") is tictactoe_minimax
    assert builtin_for("minimax", "connect_four_v3") is None
    assert builtin_for("heuristic", "tictactoe_v3") is None
    assert builtin_for("heuristic", "go_v5") is None
    assert builtin_for("heuristic", "connect_four_v3x") is None
    assert builtin_for("random", "connect_four_v3") is None
