"""HazardGridWorld: a GridWorld whose shortest path crosses hazard cells, for constrained RL.

In the spirit of AI Safety Gridworlds' island navigation: stepping onto a hazard cell costs 1
(``info["cost"] = 1.0``, ``info["violation"] = "hazard"``, Safety-Gymnasium's convention) but does not end the
episode, so a reward-only agent takes the short hazardous path and a constrained one must learn the longer safe
path. Spec (docs/envs.md, HazardGridWorld), default layout (5 x 7, ``H`` hazard, ``S`` start, ``G`` goal)::

    . . . . . . .
    . . . H . . .
    . . . H . . .
    . . . H . . .
    S . . H . . G

- Observation: the cell index ``row * n_cols + col`` (``Discrete(35)``); actions 0 up, 1 down, 2 left, 3 right.
- Reward as GridWorld: -1 per step (also into a wall, where the agent stays), +100 for the step onto the goal,
  which terminates; truncation after ``max_steps`` (default 50). ``hazard_penalty`` (default 0) is added to the
  reward of every hazard step: the book's fixed-penalty style, for comparison with a constraint.
- Shortest path: 6 steps through one hazard cell, return 95, cost 1; shortest safe path (over the top row):
  14 steps, return 87, cost 0.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from sbagents.envs.bounds import check_number
from sbagents.envs.gridworld import GridWorldEnv

DEFAULT_HAZARDS = ((1, 3), (2, 3), (3, 3), (4, 3))
HAZARD_COST = 1.0


class HazardGridWorldEnv(GridWorldEnv):
    """GridWorld with hazard cells that cost 1 per step on them and do not end the episode.

    :param hazards: hazard cells ``(row, col)`` (not the start or the goal).
    :param hazard_penalty: added to the reward of a step that ends on a hazard cell (0: the cost only).
    Other parameters as :class:`~sbagents.envs.gridworld.GridWorldEnv` (no obstacles by default).
    """

    def __init__(
        self,
        size: int | Sequence[int] = (5, 7),
        start: Sequence[int] = (4, 0),
        goal: Sequence[int] = (4, 6),
        obstacles: Iterable[Sequence[int]] = (),
        hazards: Iterable[Sequence[int]] = DEFAULT_HAZARDS,
        hazard_penalty: float = 0.0,
        max_steps: int = 50,
        render_mode: str | None = None,
    ) -> None:
        super().__init__(size, start, goal, obstacles, max_steps, render_mode)
        if isinstance(hazards, str) or not isinstance(hazards, Iterable):
            raise ValueError(f"hazards must be a list of (row, col) cells, got {hazards!r}")
        self.hazards = frozenset(self._cell(c, "hazard") for c in hazards)
        if {self.start, self.goal} & self.hazards or self.hazards & self.obstacles:
            raise ValueError("hazards must not be the start, the goal or an obstacle")
        self.hazard_penalty = check_number(hazard_penalty, "hazard_penalty", high=0.0)

    def step(self, action: Any) -> tuple[np.int64, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = super().step(action)
        on_hazard = self.agent in self.hazards
        info["cost"] = HAZARD_COST if on_hazard else 0.0
        info["violation"] = "hazard" if on_hazard else None
        return obs, reward + (self.hazard_penalty if on_hazard else 0.0), terminated, truncated, info

    def grid_text(self, path: Iterable[tuple[int, int]] = ()) -> str:
        """GridWorld's text grid with ``H`` for hazard cells (under the agent, goal and path marks)."""
        lines = [line.split(" ") for line in super().grid_text(path).split("\n")]
        for r, c in self.hazards:
            if lines[r][c] == ".":
                lines[r][c] = "H"
        return "\n".join(" ".join(line) for line in lines)
