"""Scripted experts of the book's envs (see :mod:`sbagents.baselines`): the controllers of GridWorld's shortest path,
HazardGridWorld's shortest safe path and SmartHome's true state, and TreasureHunt's greedy team (a policy of the team's
VecEnv). The Kuka envs' experts are their own scripts (:class:`sbagents.envs.kuka.scripted.ScriptedPusher`,
:class:`sbagents.envs.kuka.scripted_pick.ScriptedPicker`).
"""

from __future__ import annotations

from collections import deque
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sbagents.envs.gridworld import ACTION_DELTAS, GridWorldEnv
from sbagents.envs.treasure_hunt import ACTION_DELTAS as TREASURE_MOVES

Cell = tuple[int, int]
#: TreasureHunt's action that keeps an agent where it is.
STAY = 4


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


class GreedyTreasureTeam:
    """TreasureHunt's (``treasure_hunt_v0``) team expert: in each copy of the team, the treasures still present are
    shared out greedily (the closest agent-treasure pair first, by steps around the obstacles), and each agent takes
    a step along a shortest path to its treasure (agents left without one head for the closest). It reads each copy's
    true state (positions, treasures, obstacles), so it works with either observation mode.

    :param venv: the team's VecEnv of one shared policy (slot ``k``: agent ``k % n_agents`` of copy
        ``k // n_agents``).
    """

    #: Built on the team's VecEnv (not on one env per slot, as a controller is).
    acts_on_vec_env: ClassVar[bool] = True

    def __init__(self, venv: Any) -> None:
        self.venv = venv
        self.size = int(venv.get_attr("grid_size", [0])[0])
        self.blocked = {_cell(cell) for cell in venv.get_attr("obstacles", [0])[0]}
        self.n_agents = len(venv.get_attr("possible_agents", [0])[0])
        self._distance_maps: dict[Cell, dict[Cell, int]] = {}

    def _distances(self, target: Cell) -> dict[Cell, int]:
        """Steps to ``target`` from every cell that reaches it around the obstacles (breadth-first, cached)."""
        if target not in self._distance_maps:
            distance, queue = {target: 0}, deque([target])
            while queue:
                row, col = queue.popleft()
                for d_row, d_col in TREASURE_MOVES[:4]:
                    cell = (row + d_row, col + d_col)
                    inside = 0 <= cell[0] < self.size and 0 <= cell[1] < self.size
                    if inside and cell not in self.blocked and cell not in distance:
                        distance[cell] = distance[(row, col)] + 1
                        queue.append(cell)
            self._distance_maps[target] = distance
        return self._distance_maps[target]

    def _copy_actions(self, cells: list[Any], treasures: list[Any], present: list[bool]) -> list[int]:
        """Each agent's action in one copy."""
        positions = [_cell(p) for p in cells]
        left = [_cell(t) for t, here in zip(treasures, present, strict=True) if here]
        far = self.size * self.size + 1
        target: dict[int, Cell] = {}
        pairs = sorted((self._distances(t).get(p, far), i, t) for i, p in enumerate(positions) for t in left)
        taken: set[Cell] = set()
        for _, i, t in pairs:
            if i not in target and t not in taken:
                target[i] = t
                taken.add(t)
        actions = []
        for i, position in enumerate(positions):
            goal = target.get(i) or min(left, key=lambda t: self._distances(t).get(position, far), default=None)
            if goal is None:
                actions.append(STAY)
                continue
            distance = self._distances(goal)
            row, col = position
            steps = [distance.get((row + d_row, col + d_col), far) for d_row, d_col in TREASURE_MOVES[:4]]
            actions.append(int(np.argmin(steps)) if min(steps) < distance.get((row, col), far) else STAY)
        return actions

    def predict(self, obs: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        """The team's actions, slot by slot (``(num_envs,)``)."""
        n_copies = self.venv.num_envs // self.n_agents
        firsts = [c * self.n_agents for c in range(n_copies)]
        positions = self.venv.get_attr("positions", firsts)
        treasures = self.venv.get_attr("treasures", firsts)
        present = self.venv.get_attr("present", firsts)
        actions = [a for c in range(n_copies) for a in self._copy_actions(positions[c], treasures[c], present[c])]
        return np.asarray(actions, dtype=np.int64), state


def _cell(value: Any) -> Cell:
    """``(row, col)`` of a pair."""
    return int(value[0]), int(value[1])
