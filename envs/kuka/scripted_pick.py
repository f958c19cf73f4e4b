"""A scripted controller for :class:`~sbagents.envs.kuka.pick.KukaPickAndPlaceEnv`: open, go above the
cube, descend, close, lift, carry to the target, hold.

It reads the observation only (TCP position, finger width, observed cube position, desired goal), never
the simulator, so it sees the robust variant's sensor noise; until the jaw closes it averages the observed
cube positions. The TCP moves straight to each waypoint at up to one full action (``ee_step``) per step.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from sbagents.envs.kuka.pick import KukaPickAndPlaceEnv
from sbagents.envs.kuka.scripted import run_episode

__all__ = ["ScriptedPicker", "run_episode"]

#: Phases in order; ``predict`` moves to the next when the current waypoint is reached.
PHASES = ("above", "descend", "close", "lift", "carry")


class ScriptedPicker:
    """Waypoint controller for :class:`~sbagents.envs.kuka.pick.KukaPickAndPlaceEnv` and its subclasses.

    :param env: the environment (wrappers allowed).
    :param hover: height (m) of the TCP above the cube's centre before descending.
    :param grasp_depth: how far (m) below the cube's centre the TCP goes to grasp (clipped so the
        fingertips stay above the table).
    :param close_steps: steps with the jaw closing before lifting.
    :param clearance: height (m) the cube is lifted above the higher of its start and the target before
        the carry.
    :param tolerance: distance (m) at which a waypoint counts as reached.
    :param min_samples: observations of the resting cube to average before descending (the TCP waits above
        the cube until it has them). Default: 25 when the env's ``noise_level`` is positive (0.05 / sqrt(25)
        = 1 cm; measured on RobustKukaPickAndPlace seeds 100-299: 20 -> 98%, 25 -> 99%, 30 -> 97.5% success, the
        longer wait leaving too few steps to carry), else 1.
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        hover: float = 0.08,
        grasp_depth: float = 0.005,
        close_steps: int = 3,
        clearance: float = 0.04,
        tolerance: float = 0.015,
        min_samples: int | None = None,
    ) -> None:
        base = env.unwrapped
        if not isinstance(base, KukaPickAndPlaceEnv):
            raise TypeError(f"ScriptedPicker needs a KukaPickAndPlaceEnv, got {type(base).__name__}")
        self.env = base
        self.hover = hover
        self.grasp_depth = grasp_depth
        self.close_steps = close_steps
        self.clearance = clearance
        self.tolerance = tolerance
        if min_samples is None:
            min_samples = 25 if base.task.noise_level > 0 else 1
        self.min_samples = min_samples
        self.reset()

    def reset(self) -> None:
        """Forget the episode (call after every ``env.reset``)."""
        self.phase = PHASES[0]
        self._sum = np.zeros(3)
        self._count = 0
        self._closing = 0
        self._grasp_offset = np.zeros(3)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """Action ``(4,)`` in ``[-1, 1]``: TCP displacement (3) and finger-width change (1)."""
        flat = np.asarray(obs["observation"], dtype=np.float64)
        ee, block_obs = flat[:3], flat[7:10]
        target = np.asarray(obs["desired_goal"], dtype=np.float64)
        if self.phase in ("above", "descend"):
            self._sum += block_obs
            self._count += 1
        block = self._sum / max(self._count, 1)
        grasp_z = max(block[2] - self.grasp_depth, float(self.env.ee_low[2]) + 0.002)
        grasp = np.array([block[0], block[1], grasp_z])
        fingers = 1.0
        if self.phase == "above":
            goal = grasp + np.array([0.0, 0.0, self.hover])
            if np.linalg.norm(ee - goal) < self.tolerance and self._count >= self.min_samples:
                self.phase = "descend"
        if self.phase == "descend":
            goal = grasp
            if np.linalg.norm(ee - goal) < self.tolerance / 2:
                self.phase = "close"
                self._grasp_offset = ee - block
        if self.phase == "close":
            goal, fingers = grasp, -1.0
            self._closing += 1
            if self._closing > self.close_steps:
                self.phase = "lift"
        if self.phase == "lift":
            goal, fingers = grasp.copy(), -1.0
            goal[2] = max(grasp[2], target[2] + self._grasp_offset[2]) + self.clearance
            if abs(ee[2] - goal[2]) < self.tolerance:
                self.phase = "carry"
        if self.phase == "carry":  # then hold: stay there with the jaw closed
            fingers = -1.0
            goal = target + self._grasp_offset
            goal[2] += self.clearance * min(1.0, float(np.linalg.norm((ee - goal)[:2])) / 0.05)
        action = np.empty(4, dtype=np.float32)
        action[:3] = np.clip((goal - ee) / self.env.ee_step, -1.0, 1.0)
        action[3] = fingers
        return action

    def predict(
        self, obs: dict[str, np.ndarray], state: Any = None, episode_start: Any = None, deterministic: bool = True
    ) -> tuple[np.ndarray, None]:
        """SB3-style ``predict`` for a single (non-vectorised) env: ``(action, None)``."""
        return self.act(obs), None
