"""Built-in scripted opponents for PettingZoo classic games.

Each opponent is a plain function ``policy(observation, action_mask, rng) -> action`` that reads one agent's
observation of a PettingZoo AEC env (``env.observe(agent)["observation"]`` and ``["action_mask"]``) and returns a legal
action. They need no training and no torch, so they serve as fixed benchmarks and sparring partners:

- ``"heuristic"`` for ``connect_four_v3``: :func:`connect_four_heuristic` (win, else block, else prefer the centre).
- ``"opportunist"`` for ``connect_four_v3``: :func:`connect_four_opportunist` (win if it can, else random).
- ``"minimax"`` for ``tictactoe_v3``: :func:`tictactoe_minimax` (perfect play; never loses).
- ``"opportunist"`` for ``tictactoe_v3``: :func:`tictactoe_opportunist` (win if it can, else random).

:func:`builtin_for` looks one up by opponent name and game name (``"connect_four_v3"``; later versions of the same game
match too).

Board layouts (checked against the pettingzoo 1.27 sources and by stepping the real envs in the tests):

- connect four: observation ``(6, 7, 2)``, channel 0 the mover's pieces, channel 1 the opponent's; row 0 is the *top*
  row and a piece dropped in column ``c`` lands on the largest free row index; the action is the column ``0..6``.
- tic-tac-toe: observation ``(3, 3, 2)`` with ``observation[i, j]`` the square played by action ``3 * i + j`` (the env
  builds it as ``board.squares.reshape(3, 3)``); channel 0 the mover's marks, channel 1 the opponent's. (The env's
  *rendering* shows square ``a`` at screen row ``a % 3``, column ``a // 3``: the observation is the transpose of the
  picture, which changes nothing for play since the winning lines are symmetric under transposition.)
"""

from __future__ import annotations

import re
from collections.abc import Callable
from functools import cache

import numpy as np

#: ``policy(observation, action_mask, rng) -> action`` of a scripted opponent.
OpponentFn = Callable[[np.ndarray, np.ndarray, np.random.Generator], int]

# --------------------------------------------------------------------------------------------------------------------
# Connect four
# --------------------------------------------------------------------------------------------------------------------

_C4_ROWS = 6
_C4_COLS = 7
_C4_CELLS = _C4_ROWS * _C4_COLS


def _connect_four_lines() -> np.ndarray:
    """The 69 winning lines of connect four as flat cell indices ``row * 7 + col``, shape ``(69, 4)``."""
    lines = []
    for row in range(_C4_ROWS):
        for col in range(_C4_COLS):
            for d_row, d_col in ((0, 1), (1, 0), (1, 1), (1, -1)):  # horizontal, vertical, both diagonals
                end_row, end_col = row + 3 * d_row, col + 3 * d_col
                if 0 <= end_row < _C4_ROWS and 0 <= end_col < _C4_COLS:
                    lines.append([(row + k * d_row) * _C4_COLS + col + k * d_col for k in range(4)])
    return np.array(lines, dtype=np.intp)


#: Every line of four cells as flat indices ``row * 7 + col``: 24 horizontal, 21 vertical, 12 + 12 diagonal.
C4_LINES = _connect_four_lines()
C4_LINES.setflags(write=False)
#: "Prefer the centre" weights of the random fallback, column 0..6.
C4_CENTRE_WEIGHTS = (1, 2, 3, 4, 3, 2, 1)

# The heuristic works on bitboards (Python ints): cell (row, col) is bit ``8 * row + col``, so each board row is one
# byte (as ``np.packbits(..., bitorder="little")`` gives it) and bit 7 of every byte is an always-empty sentinel column.
# Shifting by 1 (horizontal), 8 (vertical), 9 and 7 (the diagonals) then never wraps a line from one row into the next:
# a wrapped line runs through the sentinel, which is never set. This is equivalent to checking the 69 lines above.
_BB_SHIFTS = (1, 7, 8, 9)
_BB_CELLS = sum(1 << (8 * row + col) for row in range(_C4_ROWS) for col in range(_C4_COLS))
_BB_BOTTOM = sum(1 << (8 * (_C4_ROWS - 1) + col) for col in range(_C4_COLS))
_BB_ROWS_REPEAT = sum(1 << (8 * row) for row in range(_C4_ROWS))  # column byte -> those columns in every row


def _threats(pieces: int) -> int:
    """Bitboard of the cells that would complete four in a row for ``pieces`` (occupied cells included)."""
    out = 0
    for s in _BB_SHIFTS:
        up1, up2, down1, down2 = pieces << s, pieces << 2 * s, pieces >> s, pieces >> 2 * s
        out |= (up1 & up2 & ((pieces << 3 * s) | down1)) | (down1 & down2 & ((pieces >> 3 * s) | up1))
    return out


def _pick_column(cells: int, rng: np.random.Generator) -> int:
    """The column of one of the set bits of bitboard ``cells``, uniformly at random over the distinct columns."""
    columns = []
    while cells:
        low = cells & -cells
        columns.append((low.bit_length() - 1) & 7)
        cells ^= low
    if len(columns) == 1:
        return columns[0]
    columns = sorted(set(columns))
    return columns[min(int(rng.random() * len(columns)), len(columns) - 1)]


def _c4_bits(observation: np.ndarray, action_mask: np.ndarray, who: str) -> tuple[int, int, int, int]:
    """Bitboards of a connect four position: legal columns (a byte), the mover's pieces, the opponent's, and the
    cells a piece would land on in the legal columns."""
    legal = int(np.packbits(np.asarray(action_mask).reshape(_C4_COLS) != 0, bitorder="little")[0])
    if not legal:
        raise ValueError(f"{who}: the action mask allows no column")
    planes = np.asarray(observation).reshape(_C4_ROWS, _C4_COLS, 2).transpose(2, 0, 1) != 0
    packed = np.packbits(planes, axis=2, bitorder="little").tobytes()  # 6 row bytes of mine, then 6 of theirs
    mine = int.from_bytes(packed[:_C4_ROWS], "little")
    theirs = int.from_bytes(packed[_C4_ROWS:], "little")
    filled = mine | theirs
    # A piece lands on an empty cell whose cell below (bit + 8) is filled, or on the bottom row.
    landing = ~filled & ((filled >> 8) | _BB_BOTTOM) & _BB_CELLS & (legal * _BB_ROWS_REPEAT)
    return legal, mine, theirs, landing


def connect_four_opportunist(observation: np.ndarray, action_mask: np.ndarray, rng: np.random.Generator) -> int:
    """Random play that never misses a win: a winning column if there is one, else a uniformly random legal one.

    A sparring partner for self-play (``mix: {opportunist: ...}``): random-looking positions in which a threat left
    open is punished at once. Same arguments and bitboards as :func:`connect_four_heuristic`.
    """
    legal, mine, _, landing = _c4_bits(observation, action_mask, "connect_four_opportunist")
    wins = _threats(mine) & landing
    if wins:
        return _pick_column(wins, rng)
    columns = [col for col in range(_C4_COLS) if legal >> col & 1]
    return columns[min(int(rng.random() * len(columns)), len(columns) - 1)]


def connect_four_heuristic(observation: np.ndarray, action_mask: np.ndarray, rng: np.random.Generator) -> int:
    """
    A one-ply connect four player: win if it can, else block, else prefer the centre.

    1. If dropping in some legal column completes four in a row (horizontal, vertical or diagonal) for the mover,
       play it (a random one if several do).
    2. Else, if the opponent would complete four by dropping in some legal column, play there to block it (a random
       one if there are several such columns: the game is lost anyway).
    3. Else draw a legal column at random with weights ``[1, 2, 3, 4, 3, 2, 1]`` renormalised over the legal ones.

    Works on bitboards (Python ints), about 20 microseconds a call.

    :param observation: the mover's observation, shape ``(6, 7, 2)``: channel 0 its own pieces, channel 1 the
        opponent's, row 0 the top row (a dropped piece lands on the largest free row index).
    :param action_mask: shape ``(7,)``, nonzero for the legal columns.
    :param rng: source of the random choices.
    :return: a column ``0..6`` that ``action_mask`` allows.
    :raises ValueError: when ``action_mask`` allows no column.
    """
    legal, mine, theirs, landing = _c4_bits(observation, action_mask, "connect_four_heuristic")
    if landing:
        wins = _threats(mine) & landing
        if wins:
            return _pick_column(wins, rng)
        blocks = _threats(theirs) & landing
        if blocks:
            return _pick_column(blocks, rng)
    weights = [weight if legal >> col & 1 else 0 for col, weight in enumerate(C4_CENTRE_WEIGHTS)]
    draw = rng.random() * sum(weights)
    for column, weight in enumerate(weights):
        draw -= weight
        if weight and draw < 0:
            return column
    return max(col for col, weight in enumerate(weights) if weight)  # float round-off at the very top of the range


# --------------------------------------------------------------------------------------------------------------------
# Tic-tac-toe
# --------------------------------------------------------------------------------------------------------------------

#: The 8 winning lines of tic-tac-toe as action indices (rows, columns and diagonals of ``squares.reshape(3, 3)``).
TTT_LINES = ((0, 1, 2), (3, 4, 5), (6, 7, 8), (0, 3, 6), (1, 4, 7), (2, 5, 8), (0, 4, 8), (2, 4, 6))


def _ttt_won(board: tuple[int, ...]) -> bool:
    """Whether the mover (the ``1`` marks) has three in a line."""
    return any(board[a] == board[b] == board[c] == 1 for a, b, c in TTT_LINES)


@cache
def _ttt_move_scores(board: tuple[int, ...]) -> tuple[tuple[int, int], ...]:
    """
    Negamax score of every empty square for the player to move.

    :param board: 9 squares in action order, ``1`` the mover's marks, ``-1`` the opponent's, ``0`` empty.
    :return: ``(move, score)`` pairs; a win with ``n`` marks on the board after it scores ``10 - n`` (faster wins score
        higher, slower losses score less negative), a draw ``0``.
    """
    marks_after = 10 - board.count(0)
    scores = []
    for move in range(9):
        if board[move]:
            continue
        child = (*board[:move], 1, *board[move + 1 :])
        if _ttt_won(child):
            score = 10 - marks_after
        elif marks_after == 9:
            score = 0
        else:
            score = -max(s for _, s in _ttt_move_scores(tuple(-v for v in child)))
        scores.append((move, score))
    return tuple(scores)


@cache
def _ttt_optimal_moves(key: bytes) -> tuple[int, ...]:
    """The optimal moves of a position, keyed by ``observation.astype(int8).tobytes()`` (an ``(3, 3, 2)`` array)."""
    marks = np.frombuffer(key, dtype=np.int8).reshape(9, 2) != 0
    board = tuple(int(mine) - int(theirs) for mine, theirs in marks)
    scored = _ttt_move_scores(board)
    if not scored:
        return ()
    best = max(score for _, score in scored)
    return tuple(move for move, score in scored if score == best)


def tictactoe_minimax(observation: np.ndarray, action_mask: np.ndarray, rng: np.random.Generator) -> int:
    """
    A perfect tic-tac-toe player: full negamax over the game tree, memoised on the board.

    Among the optimal moves (winning fastest, else drawing, else losing slowest) it picks one uniformly at random, so
    self-play is not one fixed game. It never loses. The first call searches the whole tree (about 5,500 positions,
    tens of milliseconds); later calls are cache lookups.

    :param observation: the mover's observation, shape ``(3, 3, 2)``: channel 0 its own marks, channel 1 the
        opponent's; ``observation[i, j]`` is the square of action ``3 * i + j``.
    :param action_mask: shape ``(9,)``, nonzero for the legal squares.
    :param rng: source of the tie-breaking choice.
    :return: a square ``0..8`` that ``action_mask`` allows.
    :raises ValueError: when ``action_mask`` allows no square.
    """
    legal = np.asarray(action_mask).reshape(9) != 0
    key = np.ascontiguousarray(np.asarray(observation).reshape(3, 3, 2), dtype=np.int8).tobytes()
    optimal = [move for move in _ttt_optimal_moves(key) if legal[move]]
    if not optimal:  # no legal move, or the mask disagrees with the board: stay legal
        optimal = np.flatnonzero(legal).tolist()
        if not optimal:
            raise ValueError("tictactoe_minimax: the action mask allows no square")
    if len(optimal) == 1:
        return int(optimal[0])
    return int(optimal[min(int(rng.random() * len(optimal)), len(optimal) - 1)])


def tictactoe_opportunist(observation: np.ndarray, action_mask: np.ndarray, rng: np.random.Generator) -> int:
    """Random play that never misses a win: a square completing three of the mover's marks if there is one, else a
    uniformly random legal square. Connect four's :func:`connect_four_opportunist` for tic-tac-toe: in random-looking
    positions, a line left open is punished at once. Same arguments as :func:`tictactoe_minimax`.

    :raises ValueError: when ``action_mask`` allows no square.
    """
    legal = np.flatnonzero(np.asarray(action_mask).reshape(9) != 0).tolist()
    if not legal:
        raise ValueError("tictactoe_opportunist: the action mask allows no square")
    mine = np.asarray(observation).reshape(9, 2)[:, 0] != 0
    wins = [a for a in legal if any(a in line and sum(mine[s] for s in line if s != a) == 2 for line in TTT_LINES)]
    choices = wins or legal
    return int(choices[min(int(rng.random() * len(choices)), len(choices) - 1)])


# --------------------------------------------------------------------------------------------------------------------
# Lookup
# --------------------------------------------------------------------------------------------------------------------

#: Opponent name -> game (last component of the pettingzoo module, e.g. ``"connect_four_v3"``) -> policy.
BUILTIN_OPPONENTS: dict[str, dict[str, OpponentFn]] = {
    "heuristic": {"connect_four_v3": connect_four_heuristic},
    "opportunist": {"connect_four_v3": connect_four_opportunist, "tictactoe_v3": tictactoe_opportunist},
    "minimax": {"tictactoe_v3": tictactoe_minimax},
}

_VERSION_SUFFIX = re.compile(r"_v\d+$")


def builtin_for(name: str, game: str) -> OpponentFn | None:
    """
    The built-in opponent ``name`` for ``game``, or None when there is none.

    :param name: opponent name, a key of :data:`BUILTIN_OPPONENTS` (``"heuristic"``, ``"minimax"``).
    :param game: the game's module name, e.g. ``"connect_four_v3"`` (a dotted path such as
        ``"pettingzoo.classic.connect_four_v3"`` is cut to its last component). Other versions of a known game match
        too: ``"connect_four_v4"`` gets the ``connect_four_v3`` opponent.
    :return: the policy ``(observation, action_mask, rng) -> action``, or None.
    """
    table = BUILTIN_OPPONENTS.get(name)
    if table is None:
        return None
    game = game.rsplit(".", 1)[-1]
    if game in table:
        return table[game]
    base = _VERSION_SUFFIX.sub("", game)
    for known, policy in table.items():
        if _VERSION_SUFFIX.sub("", known) == base:
            return policy
    return None
