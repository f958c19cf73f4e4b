"""A user's own env package for the ``--gym-packages`` tests: importing it registers ``TinyEnv-v0``.

``TinyEnv-v0`` is a corridor of ``length`` cells: the agent starts in cell 0 and moves left (0) or right (1);
every step costs -1 and reaching the last cell gives +10 and ends the episode (truncated after
``max_steps``). Optimal return for the default length 5: four moves, three -1 steps and the +10 step = 7.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces


class TinyEnv(gym.Env[np.int64, np.int64]):
    """The corridor (see the module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}
    obs_names = ("cell",)
    action_names = ("move",)

    def __init__(self, length: int = 5, max_steps: int = 20, render_mode: str | None = None) -> None:
        self.length, self.max_steps, self.render_mode = length, max_steps, render_mode
        self.observation_space = spaces.Discrete(length)
        self.action_space = spaces.Discrete(2)
        self.pos = 0
        self.steps = 0

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.int64, dict]:
        super().reset(seed=seed)
        self.pos, self.steps = 0, 0
        return np.int64(self.pos), {}

    def step(self, action: Any) -> tuple[np.int64, float, bool, bool, dict]:
        self.pos = int(np.clip(self.pos + (1 if int(action) == 1 else -1), 0, self.length - 1))
        self.steps += 1
        terminated = self.pos == self.length - 1
        reward = 10.0 if terminated else -1.0
        truncated = not terminated and self.steps >= self.max_steps
        info = {"is_success": terminated} if terminated or truncated else {}
        return np.int64(self.pos), reward, terminated, truncated, info

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        frame = np.full((16, 16 * self.length, 3), 255, dtype=np.uint8)
        frame[:, 16 * self.pos : 16 * (self.pos + 1)] = (0, 0, 200)
        return frame


gym.register(id="TinyEnv-v0", entry_point="tiny_env_pkg:TinyEnv")
