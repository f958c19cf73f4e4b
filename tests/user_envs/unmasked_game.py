"""A turn-based AEC env without action masks (``--env tests.user_envs.unmasked_game``): not trainable with masks."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import AECEnv


class CountingGame(AECEnv):
    """Two players add 1 or 2 in turns; whoever reaches 5 wins. Box observations, no action mask."""

    metadata = {"name": "counting_v0", "render_modes": []}

    def __init__(self) -> None:
        super().__init__()
        self.possible_agents = ["a", "b"]
        self.total = 0

    def observation_space(self, agent: str) -> spaces.Space:
        return spaces.Box(0, 5, (1,), np.float32)

    def action_space(self, agent: str) -> spaces.Space:
        return spaces.Discrete(2)

    def observe(self, agent: str) -> np.ndarray:
        return np.array([self.total], np.float32)

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> None:
        self.agents = list(self.possible_agents)
        self.total = 0
        self.rewards = dict.fromkeys(self.agents, 0.0)
        self._cumulative_rewards = dict.fromkeys(self.agents, 0.0)
        self.terminations = dict.fromkeys(self.agents, False)
        self.truncations = dict.fromkeys(self.agents, False)
        self.infos: dict[str, dict[str, Any]] = {a: {} for a in self.agents}
        self.agent_selection = "a"

    def step(self, action: int) -> None:
        if self.terminations[self.agent_selection]:
            self._was_dead_step(action)
            return
        self.total += int(action) + 1
        if self.total >= 5:
            winner = self.agent_selection
            self.rewards = {a: 1.0 if a == winner else -1.0 for a in self.agents}
            self.terminations = dict.fromkeys(self.agents, True)
        self.agent_selection = "b" if self.agent_selection == "a" else "a"
        self._accumulate_rewards()


def env() -> CountingGame:
    """PettingZoo's module convention: ``env()`` builds the game."""
    return CountingGame()
