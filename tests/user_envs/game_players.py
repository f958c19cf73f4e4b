"""A user's own game opponent for ``--opponent tests.user_envs.game_players:lowest_legal``."""

from __future__ import annotations

import numpy as np


def lowest_legal(observation: np.ndarray, action_mask: np.ndarray) -> int:
    """The legal action with the lowest index."""
    return int(np.flatnonzero(action_mask)[0])
