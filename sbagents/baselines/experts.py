"""Scripted experts of the book's envs (controllers, see :mod:`sbagents.baselines`): GridWorld's shortest path,
HazardGridWorld's shortest safe path, SmartHome's controller of the true state. The Kuka envs' experts are their own
scripts (:class:`sbagents.envs.kuka.scripted.ScriptedPusher`, :class:`sbagents.envs.kuka.scripted_pick.ScriptedPicker`).
"""

from __future__ import annotations

from collections import deque
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sbagents.envs.gridworld import ACTION_DELTAS, GridWorldEnv

Cell = tuple[int, int]


class ShortestPath:
    """GridWorld's (and HazardGridWorld's) expert: a step along a shortest path to the goal from the observed cell,
    around the obstacles and, in HazardGridWorld, around the hazards while a safe path exists (the env's spec: the
    shortest safe path is 14 steps, return 87, cost 0; GridWorld's default: 8 steps, return 93).

    :param env: the env (wrappers allowed).
    :param safe: avoid hazard cells where a path around them exists.
    """

    def __init__(self, env: gym.Env[Any, Any], safe: bool = True) -> None:
        base = env.unwrapped
        if not isinstance(base, GridWorldEnv):
            raise TypeError(f"ShortestPath needs a GridWorld, got {type(base).__name__}")
        self.n_rows, self.n_cols = base.n_rows, base.n_cols
        blocked = set(base.obstacles)
        hazards = set(getattr(base, "hazards", ())) if safe else set()
        self.distance = self._distances(base.goal, blocked | hazards)
        if base.start not in self.distance:  # no safe path: the hazards are crossed after all
            self.distance = self._distances(base.goal, blocked)

    def _distances(self, goal: Cell, blocked: set[Cell]) -> dict[Cell, int]:
        """Steps to ``goal`` from every cell that reaches it without entering ``blocked`` (breadth-first)."""
        distance = {goal: 0}
        queue = deque([goal])
        while queue:
            row, col = queue.popleft()
            for d_row, d_col in ACTION_DELTAS:
                cell = (row + d_row, col + d_col)
                if (0 <= cell[0] < self.n_rows and 0 <= cell[1] < self.n_cols and cell not in blocked
                        and cell not in distance):
                    distance[cell] = distance[(row, col)] + 1
                    queue.append(cell)
        return distance

    def reset(self) -> None:
        """Nothing to forget: the path depends on the cell only."""

    def act(self, obs: Any) -> int:
        """The action (0 up, 1 down, 2 left, 3 right) to the neighbour closest to the goal (the first on ties)."""
        row, col = divmod(int(obs), self.n_cols)
        unreachable = self.n_rows * self.n_cols + 1
        steps = [self.distance.get((row + d_row, col + d_col), unreachable) for d_row, d_col in ACTION_DELTAS]
        return int(np.argmin(steps))


class ComfortController:
    """SmartHome's expert: moves the temperature and the light to the user's preferences as far as one action
    allows, reading the env's true state and preferences (which the observation shows noisy, or hides after the
    first steps in ``SmartHomePrefOnce``). Each degree or lux closed is worth more than its energy penalty (0.1 per
    degree, 0.005 per lux, against an error of 1 and 0.5 per step that follows).

    :param env: the env (wrappers allowed).
    """

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        from sbagents.envs.smart_home import SmartHomeEnv

        base = env.unwrapped
        if not isinstance(base, SmartHomeEnv):
            raise TypeError(f"ComfortController needs a SmartHome env, got {type(base).__name__}")
        self.env = base
        space = base.action_space
        assert isinstance(space, spaces.Box)
        self.low, self.high = space.low, space.high

    def reset(self) -> None:
        """Nothing to forget: the true state is read at every step."""

    def act(self, obs: Any) -> np.ndarray:
        """``(thermostat, dimmer)`` adjustments towards the preferences, clipped to the action space."""
        env = self.env
        wanted = np.array([env.preferred_temp - env.temperature, env.preferred_light - env.light])
        return np.clip(wanted, self.low, self.high).astype(np.float32)
