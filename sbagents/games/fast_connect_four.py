"""PettingZoo's connect four with its board checks in numpy: the same env, step for step, ~3x faster.

``pettingzoo.classic.connect_four_v3``'s ``raw_env`` checks for a winner by looping over every cell in Python
(~40 us per move, the largest cost of a self-play training run). :class:`FastConnectFourRaw` subclasses it and
replaces only ``check_for_winner``, the piece drop and ``observe`` with array operations on the same board list;
everything else (agents, rewards, terminations, rendering, seeding) is PettingZoo's own. :func:`env` wraps it
exactly as PettingZoo's ``env()`` does. ``tests/test_games_fast.py`` plays random games on both and compares every
observation, mask, reward and termination. :func:`sbagents.games.aec.make_game` uses it for
``pettingzoo.classic.connect_four_v3`` (``SBAGENTS_REFERENCE_GAMES=1`` turns it off).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pettingzoo import AECEnv
from pettingzoo.classic.connect_four import connect_four
from pettingzoo.utils import wrappers

ROWS, COLS = 6, 7


def _winning_lines() -> np.ndarray:
    """The 69 lines of four cells (flat indices row * 7 + col), shape (69, 4)."""
    lines = []
    for r in range(ROWS):
        for c in range(COLS):
            for dr, dc in ((0, 1), (1, 0), (1, 1), (-1, 1)):
                cells = [(r + k * dr, c + k * dc) for k in range(4)]
                if all(0 <= rr < ROWS and 0 <= cc < COLS for rr, cc in cells):
                    lines.append([rr * COLS + cc for rr, cc in cells])
    return np.array(lines)


LINES = _winning_lines()
#: Flat indices of each column from the bottom row up, shape (7, 6).
COLUMN_CELLS = np.array([[r * COLS + c for r in range(ROWS - 1, -1, -1)] for c in range(COLS)])


class FastConnectFourRaw(connect_four.raw_env):  # type: ignore[misc]
    """``connect_four.raw_env`` with array-based winner check, drop and observation (same results)."""

    agent_selection: str
    terminations: dict[str, bool]
    truncations: dict[str, bool]
    rewards: dict[str, float]
    board: list[int]

    def check_for_winner(self) -> bool:
        piece = self.agents.index(self.agent_selection) + 1
        board = np.asarray(self.board)
        return bool((board[LINES] == piece).all(axis=1).any())

    def step(self, action: Any) -> None:
        if self.truncations[self.agent_selection] or self.terminations[self.agent_selection]:
            return self._was_dead_step(action)
        assert self.board[0:7][action] == 0, "played illegal move."
        piece = self.agents.index(self.agent_selection) + 1
        for i in COLUMN_CELLS[action]:
            if self.board[i] == 0:
                self.board[i] = piece
                break
        next_agent = self._agent_selector.next()
        if self.check_for_winner():
            self.rewards[self.agent_selection] += 1
            self.rewards[next_agent] -= 1
            self.terminations = dict.fromkeys(self.agents, True)
        elif 0 not in self.board:
            self.terminations = dict.fromkeys(self.agents, True)
        self.agent_selection = next_agent
        self._accumulate_rewards()
        if self.render_mode == "human":
            self.render()
        return None

    def observe(self, agent: str) -> dict[str, np.ndarray]:
        board = np.asarray(self.board).reshape(ROWS, COLS)
        me = self.possible_agents.index(agent) + 1
        observation = np.stack([board == me, board == 3 - me], axis=2).astype(np.int8)
        mask = np.zeros(COLS, np.int8)
        if agent == self.agent_selection:
            mask[np.asarray(self.board[:COLS]) == 0] = 1
        return {"observation": observation, "action_mask": mask}


def env(**kwargs: Any) -> Any:
    """The wrapped env, as ``pettingzoo.classic.connect_four_v3.env(**kwargs)`` builds it."""
    game: AECEnv[str, Any, Any] = FastConnectFourRaw(**kwargs)
    game = wrappers.TerminateIllegalWrapper(game, illegal_reward=-1)
    game = wrappers.AssertOutOfBoundsWrapper(game)
    return wrappers.OrderEnforcingWrapper(game)
