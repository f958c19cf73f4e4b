"""Playing a turn-based game in a text terminal: boards drawn for the human, moves parsed, results in words.

Each function takes the game's name (``connect_four_v3`` or its base name ``connect_four``; the ``_v<digits>``
suffix is ignored) and picks the game's text form; any other masked AEC game gets a generic one (the observation
array and the legal action indices). :func:`play_game` plays one game of a PettingZoo AEC env between a person
(``ask`` / ``say``, e.g. ``input`` / ``print``) and a :class:`~sbagents.games.players.Player` in every other seat.

Layouts (pettingzoo 1.27, checked by stepping and rendering the real envs in ``tests/test_play.py``):

- connect four: action ``c`` drops a piece in column ``c`` (shown as ``c + 1``); observation row 0 is the top row.
- tic-tac-toe: pettingzoo draws square (action) ``a`` at picture row ``a % 3``, column ``a // 3``. The human's
  cells are numbered 1-9 in reading order of that picture: cell ``3 * row + col + 1`` is action ``3 * col + row``.
- texas hold'em (rlcard's limit hold'em): actions 0-3 are ``call, raise, fold, check``; rewards are in big blinds.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Any

import numpy as np

from sbagents.games.aec import MASK_KEY, OBS_KEY, base_game_name
from sbagents.games.players import Player

#: Marks of the human's and the agent's pieces, and of an empty square.
YOU, AGENT, EMPTY = "X", "O", "."
#: Entries that end the session.
QUIT_WORDS = ("q", "quit")
#: Games with their own text form (base names); others use the generic one.
BOARD_GAMES = ("connect_four", "tictactoe", "texas_holdem")
#: rlcard's limit hold'em action names by index (``rlcard.envs.limitholdem.LimitholdemEnv.actions``).
HOLDEM_ACTIONS = ("call", "raise", "fold", "check")
_STREETS = {0: "pre-flop", 3: "flop", 4: "turn", 5: "river"}


class QuitSession(Exception):
    """The human asked to stop (``q`` or ``quit``)."""


def game_kind(game: str) -> str:
    """The text form of a game: its base name if it has one of its own (:data:`BOARD_GAMES`), else ``generic``."""
    base = base_game_name(game)
    return base if base in BOARD_GAMES else "generic"


def ttt_cell(action: int) -> int:
    """The human's cell number (1-9, reading order of pettingzoo's picture) of a tic-tac-toe action."""
    return 3 * (action % 3) + action // 3 + 1


def ttt_action(cell: int) -> int:
    """The tic-tac-toe action of a cell number 1-9 (the inverse of :func:`ttt_cell`)."""
    return 3 * ((cell - 1) % 3) + (cell - 1) // 3


def _join(items: Iterable[Any]) -> str:
    return ", ".join(str(item) for item in items)


def _label(env: Any, agent: str, human: str) -> str:
    """``you``, ``agent`` (two seats) or the seat's name (more seats)."""
    if agent == human:
        return "you"
    return "agent" if len(env.possible_agents) == 2 else agent


def _cards(cards: Iterable[Any]) -> str:
    """rlcard's cards (``get_index()`` ``'HT'``: suit, rank) as ``'Th'``, space-separated (``-`` for none)."""
    names = [f"{card.get_index()[1:]}{card.get_index()[0].lower()}" for card in cards]
    return " ".join(names) if names else "-"


def render_board(game: str, env: Any, human: str) -> str:
    """The position of ``env`` (a reset PettingZoo AEC env) drawn from seat ``human``'s point of view.

    :param game: the game's name (picks the text form, see :func:`game_kind`).
    :param human: the human's agent name (``player_0``).
    """
    kind = game_kind(game)
    if kind == "texas_holdem":
        return _render_holdem(env, human)
    obs = np.asarray(env.observe(human)[OBS_KEY])
    if kind == "connect_four":
        rows = [" ".join(YOU if obs[r, c, 0] else AGENT if obs[r, c, 1] else EMPTY for c in range(obs.shape[1]))
                for r in range(obs.shape[0])]
        footer = " ".join(str(c + 1) for c in range(obs.shape[1]))
        return "\n".join([*(f"| {row} |" for row in rows), "+" + "-" * (len(footer) + 2) + "+", f"  {footer}",
                          f"{YOU} you, {AGENT} agent"])
    if kind == "tictactoe":
        def mark(row: int, col: int) -> str:
            square = obs[col, row]  # action 3 * col + row = observation[col, row] (pettingzoo's picture transposed)
            return YOU if square[0] else AGENT if square[1] else str(3 * row + col + 1)

        lines = [" " + " | ".join(mark(r, c) for c in range(3)) for r in range(3)]
        return "\n---+---+---\n".join(lines) + f"\n{YOU} you, {AGENT} agent; numbers are free cells"
    text = f"observation {tuple(obs.shape)}: {_compact(obs)}"
    if env.agent_selection == human and not game_over(env):
        text += f"\nlegal actions: {_join(np.flatnonzero(env.observe(human)[MASK_KEY]).tolist())}"
    return text


def _compact(obs: np.ndarray) -> str:
    flat = obs.reshape(-1)
    if flat.size and np.all(np.equal(np.mod(flat, 1), 0)):
        flat = flat.astype(np.int64)
    return np.array2string(flat, max_line_width=120, threshold=200, separator=" ")


def _render_holdem(env: Any, human: str) -> str:
    game = env.unwrapped.env.game  # rlcard's LimitHoldemGame
    seats = list(env.possible_agents)
    me = seats.index(human)
    chips = [int(player.in_chips) for player in game.players]
    n_public = len(game.public_cards)
    street = _STREETS.get(n_public, f"{n_public} public cards")
    stakes = ", ".join(f"{_label(env, seat, human)} {chips[i]}" for i, seat in enumerate(seats))
    lines = [f"{street}: pot {sum(chips)} ({stakes})",
             f"your hand:  {_cards(game.players[me].hand)}",
             f"board:      {_cards(game.public_cards)}"]
    # rlcard's limit hold'em marks a fold with the string 'folded', not PlayerStatus.FOLDED
    live = [i for i, player in enumerate(game.players)
            if str(getattr(player.status, "name", player.status)).lower() != "folded"]
    if game.is_over() and len(live) > 1:  # a showdown: the other hands are shown
        lines += [f"{_label(env, seats[i], human)}'s hand: {_cards(game.players[i].hand)}" for i in live if i != me]
    if not game.is_over() and env.agent_selection == human:
        mask = env.observe(human)[MASK_KEY]
        lines.append(f"legal: {_join(f'{HOLDEM_ACTIONS[a]} ({a})' for a in np.flatnonzero(mask))}")
    return "\n".join(lines)


def describe_action(game: str, action: int) -> str:
    """An action in the human's words: ``column 4``, ``cell 5``, ``raise``, ``action 3``."""
    kind = game_kind(game)
    if kind == "connect_four":
        return f"column {action + 1}"
    if kind == "tictactoe":
        return f"cell {ttt_cell(action)}"
    if kind == "texas_holdem" and 0 <= action < len(HOLDEM_ACTIONS):
        return HOLDEM_ACTIONS[action]
    return f"action {action}"


def move_prompt(game: str) -> str:
    """The input prompt of the human's move."""
    hint = {"connect_four": "column 1-7", "tictactoe": "cell 1-9", "texas_holdem": "call, raise, fold or check",
            "generic": "action index"}[game_kind(game)]
    return f"your move ({hint}; q quits): "


def accepted_moves(game: str, mask: np.ndarray) -> str:
    """What the human may enter in this position, listing the legal moves."""
    legal = np.flatnonzero(mask).tolist()
    kind = game_kind(game)
    if kind == "connect_four":
        return f"enter a column 1-{len(mask)} that is not full: {_join([a + 1 for a in legal])}"
    if kind == "tictactoe":
        return f"enter a free cell 1-9: {_join(sorted(ttt_cell(a) for a in legal))}"
    if kind == "texas_holdem":
        return f"enter one of {_join(f'{describe_action(game, a)} ({a})' for a in legal)}"
    return f"enter a legal action index: {_join(legal)}"


def parse_move(game: str, text: str, mask: np.ndarray) -> int:
    """The action the human's entry names.

    Boards take 1-based numbers (connect four columns, tic-tac-toe cells); poker takes an action name or its
    index; other games an action index.

    :raises ValueError: the entry is not a move, or not a legal one; the message says what is accepted.
    """
    mask = np.asarray(mask)
    entry = text.strip().lower()
    kind = game_kind(game)
    accepted = accepted_moves(game, mask)
    what = {"connect_four": "column", "tictactoe": "cell"}.get(kind, "action")
    if not entry:
        raise ValueError(f"no move entered; {accepted}")
    if kind == "texas_holdem" and entry in HOLDEM_ACTIONS:
        number = HOLDEM_ACTIONS.index(entry)
    else:
        try:
            number = int(entry)
        except ValueError:
            raise ValueError(f"{text.strip()!r} is not a{'n' if what == 'action' else ''} {what}; {accepted}") from None
    first, last = (1, 9) if kind == "tictactoe" else (1, len(mask)) if kind == "connect_four" else (0, len(mask) - 1)
    if not first <= number <= last:
        raise ValueError(f"there is no {what} {number}; {accepted}")
    action = ttt_action(number) if kind == "tictactoe" else number - first
    if not mask[action]:
        problem = {"connect_four": "is full", "tictactoe": "is taken"}.get(kind, "is not allowed now")
        name = describe_action(game, action) if kind == "texas_holdem" else f"{what} {number}"
        raise ValueError(f"{name} {problem}; {accepted}")
    return action


def game_over(env: Any) -> bool:
    """Whether the AEC game is over: no agents left, or every agent terminated or truncated."""
    return not env.agents or all(env.terminations[a] or env.truncations[a] for a in env.agents)


def chips_per_point(game: str, env: Any) -> float | None:
    """Chips per unit of reward (poker: the big blind, rlcard's payoffs are in big blinds), None for boards."""
    if game_kind(game) != "texas_holdem":
        return None
    return float(env.unwrapped.env.game.big_blind)


def outcome_line(reward: float, chips_per_point: float | None = None) -> str:
    """The human's result of one game (``you win``, ``draw``, ``you lose``; poker: the chips won or lost)."""
    if chips_per_point is not None:
        chips = reward * chips_per_point
        if chips == 0:
            return "result: split pot, no chips won or lost"
        noun = "chip" if abs(chips) == 1 else "chips"
        return f"result: you {'win' if chips > 0 else 'lose'} {abs(chips):g} {noun}"
    return "result: " + ("you win" if reward > 0 else "you lose" if reward < 0 else "draw") + f" ({reward:+g})"


def tally_line(rewards: Sequence[float], chips_per_point: float | None = None) -> str:
    """One line of the human's session: wins, draws, losses (poker: and the chips won)."""
    values = np.asarray(rewards, dtype=float)
    wins, draws, losses = int(np.sum(values > 0)), int(np.sum(values == 0)), int(np.sum(values < 0))
    unit = "game" if chips_per_point is None else "hand"
    text = (f"tally: {wins} win{'s' * (wins != 1)}, {draws} draw{'s' * (draws != 1)}, {losses} loss"
            f"{'es' * (losses != 1)} in {len(values)} {unit}{'s' * (len(values) != 1)}")
    if chips_per_point is not None:
        text += f"; chips won: {float(values.sum()) * chips_per_point:+g}"
    return text


def ask_move(game: str, mask: np.ndarray, ask: Callable[[str], str], say: Callable[[str], None]) -> int:
    """Ask until the human enters a legal move; a bad entry is answered with what is accepted.

    :raises QuitSession: the human entered ``q`` or ``quit``.
    """
    while True:
        text = ask(move_prompt(game))
        if text.strip().lower() in QUIT_WORDS:
            raise QuitSession
        try:
            return parse_move(game, text, mask)
        except ValueError as exc:
            say(str(exc))


def play_game(env: Any, game: str, human: str, agent: Player, ask: Callable[[str], str],
              say: Callable[[str], None], seed: int | None = None) -> dict[str, float]:
    """Play one game of the AEC ``env``: the human in seat ``human``, ``agent`` in every other seat.

    The board is drawn before each of the human's moves and when the game is over; the agent's moves are told.

    :param game: the game's name (text form, :func:`game_kind`).
    :param ask: reads the human's entry given a prompt (``input``); its EOFError / KeyboardInterrupt propagate.
    :param say: shows a text (``print``).
    :param seed: seed of ``env.reset`` (None: the env's own generator).
    :return: each seat's return (``env.rewards`` summed after every move).
    :raises QuitSession: the human quit.
    """
    env.reset(seed=seed)
    returns = dict.fromkeys(env.possible_agents, 0.0)
    while not game_over(env):
        seat = env.agent_selection
        if env.terminations[seat] or env.truncations[seat]:
            env.step(None)  # a seat out of the game (more than two seats)
            continue
        seen = env.observe(seat)
        mask = np.asarray(seen[MASK_KEY])
        if seat == human:
            say(render_board(game, env, human))
            action = ask_move(game, mask, ask, say)
            say(f"you play {describe_action(game, action)}")
        else:
            action = int(agent(seen[OBS_KEY], mask))
            who = "agent" if len(env.possible_agents) == 2 else f"agent ({seat})"
            illegal = "" if 0 <= action < len(mask) and mask[action] else " (an illegal move: the agent forfeits)"
            say(f"{who} plays {describe_action(game, action)}{illegal}")
        env.step(action)
        for name, reward in env.rewards.items():
            returns[name] += float(reward)
    say(render_board(game, env, human))
    return returns
