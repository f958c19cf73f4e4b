"""Partially observable classic control: CartPole with its velocities hidden (RL Zoo's ``CartPoleNoVel-v1``).

The observation keeps its shape ``(4,)`` and bounds; cart velocity (index 1) and pole angular velocity (index 3)
are always 0, so a policy must infer them from what it saw before: a memoryless policy cannot tell a pole falling
left from one rising left. The dynamics, reward (+1 per step), termination and the 500-step time limit are
CartPole-v1's.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.envs.classic_control.cartpole import CartPoleEnv

#: The observation indices CartPoleNoVel hides (cart velocity, pole angular velocity).
VELOCITY_INDICES: tuple[int, ...] = (1, 3)


class CartPoleNoVelEnv(CartPoleEnv):
    """CartPole-v1 whose observation shows positions only: ``[x, 0, theta, 0]``."""

    def __init__(self, render_mode: str | None = None) -> None:
        super().__init__(render_mode=render_mode)
        self._mask = np.ones(4, dtype=np.float32)
        self._mask[list(VELOCITY_INDICES)] = 0.0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = super().reset(seed=seed, options=options)
        return obs * self._mask, info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = super().step(action)
        return obs * self._mask, float(reward), terminated, truncated, info
