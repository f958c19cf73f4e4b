"""A user's own turn-based game with action masks: ``--env tests.user_envs.nim_game:nim`` (or the module itself).

Nim with one pile of 7 stones: players take 1, 2 or 3 in turns; whoever takes the last stone wins (+1, the other
-1). The first player wins with perfect play (leave a multiple of 4).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import AECEnv

PILE = 7


class Nim(AECEnv):
    """One pile, take 1-3; observation: one-hot of the stones left; mask: the takes that fit."""

    metadata = {"name": "nim_v0", "render_modes": []}

    def __init__(self, pile: int = PILE) -> None:
        super().__init__()
        self.possible_agents = ["first", "second"]
        self.pile0 = pile
        self.pile = pile

    def observation_space(self, agent: str) -> spaces.Space:
        return spaces.Dict({"observation": spaces.Box(0, 1, (self.pile0 + 1,), np.int8),
                            "action_mask": spaces.Box(0, 1, (3,), np.int8)})

    def action_space(self, agent: str) -> spaces.Space:
        return spaces.Discrete(3)

    def observe(self, agent: str) -> dict[str, np.ndarray]:
        obs = np.zeros(self.pile0 + 1, np.int8)
        obs[self.pile] = 1
        mask = np.array([self.pile >= k for k in (1, 2, 3)], np.int8)
        return {"observation": obs, "action_mask": mask}

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> None:
        self.agents = list(self.possible_agents)
        self.pile = self.pile0
        self.rewards = dict.fromkeys(self.agents, 0.0)
        self._cumulative_rewards = dict.fromkeys(self.agents, 0.0)
        self.terminations = dict.fromkeys(self.agents, False)
        self.truncations = dict.fromkeys(self.agents, False)
        self.infos: dict[str, dict[str, Any]] = {a: {} for a in self.agents}
        self.agent_selection = "first"

    def step(self, action: int) -> None:
        if self.terminations[self.agent_selection]:
            self._was_dead_step(action)
            return
        mover = self.agent_selection
        self.pile -= min(int(action) + 1, self.pile)
        other = "second" if mover == "first" else "first"
        self.rewards = dict.fromkeys(self.agents, 0.0)
        if self.pile == 0:
            self.rewards = {mover: 1.0, other: -1.0}
            self.terminations = dict.fromkeys(self.agents, True)
        self.agent_selection = other
        self._accumulate_rewards()


def nim(pile: int = PILE) -> Nim:
    """``module:callable`` form."""
    return Nim(pile)


env = nim
