"""The ``info`` keys that envs, sbagents' wrappers and the callbacks agree on.

A key named here means one thing in every package: an env reports it, a wrapper adds it, and evaluation and the
trust callbacks read it. This module imports nothing, so that a callback can take a key without loading the
package that writes it (``ACTED`` is written by :mod:`sbagents.multiagent.team`, which imports PettingZoo).
"""

from __future__ import annotations

#: Info key marking a slot whose action was not used (its agent was absent); absent means it acted.
ACTED = "sbagents_acted"

#: Per-step cost of a constrained env (Safety-Gymnasium's convention; missing means 0).
COST = "cost"

#: Per-step constraint violation flag or amount (an env that reports no ``cost`` may report this).
VIOLATION = "violation"

#: Whether the episode succeeded (Gymnasium's and SB3's ``is_success``, read at the episode's last step).
IS_SUCCESS = "is_success"

#: Info keys of a turn-based game (``SelfPlayEnv``): at a reset, the ``(seat, return)`` of games that ended before
#: the player's seat moved; at every step, 1 for an illegal move of the player; at a game's last step, the player's
#: seat index, return and outcome (-1, 0, 1).
UNPLAYED_KEY = "unplayed_games"
OUTCOME_KEY, RETURN_KEY, SEAT_KEY, ILLEGAL_KEY = "game_outcome", "game_return", "seat", "illegal_moves"
#: Keys that SB3 / Gymnasium wrappers (and sbagents' team VecEnvs) put in ``info``: never treated as env data.
INTERNAL_INFO_KEYS = frozenset(
    {"terminal_observation", "episode", "TimeLimit.truncated", "final_observation", "final_info", ACTED}
)
