"""GridWorld from chapter 2 of the book, as a Gymnasium environment.

Spec (docs/envs.md, GridWorld): a 5x5 grid, start (0, 0), goal (4, 4), obstacles on the
diagonal (1, 1), (2, 2), (3, 3). Cells are ``(row, col)`` and observations are ``row * n_cols + col``.

Deviations from the book, all documented in the README table:

- The book never ends an unsuccessful episode; we truncate after ``max_steps`` (default 100).
- Grid size, start, goal and obstacles are constructor arguments (the book's exercises ask for them).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sbagents.envs.bounds import MAX_EPISODE_STEPS, MAX_GRID_SIDE, check_int
from sbagents.envs.text_grid import TextGridRendering

Cell = tuple[int, int]

#: Row/column deltas of the four actions: 0 up, 1 down, 2 left, 3 right.
ACTION_DELTAS: tuple[Cell, ...] = ((-1, 0), (1, 0), (0, -1), (0, 1))
ACTION_NAMES: tuple[str, ...] = ("up", "down", "left", "right")

STEP_REWARD = -1.0
WALL_REWARD = -1.0
OBSTACLE_REWARD = -10.0
GOAL_REWARD = 100.0

_COLOURS = {"A": (30, 110, 230), "G": (40, 170, 60), "X": (60, 60, 60), ".": (235, 235, 235), "*": (170, 200, 240),
            "H": (240, 150, 40)}


def _is_int(value: Any) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def _int_pair(value: Any, what: str) -> Cell:
    """``(row, col)`` from a pair of integers, or ValueError naming ``what``."""
    if isinstance(value, str) or not isinstance(value, Sequence | np.ndarray) or len(value) != 2 \
            or not all(_is_int(v) for v in value):
        raise ValueError(f"{what} must be a pair of integers (row, col), got {value!r}")
    return int(value[0]), int(value[1])


class GridWorldEnv(TextGridRendering, gym.Env[np.int64, np.int64]):
    """Deterministic grid navigation with obstacles and a single goal.

    :param size: grid side length, or ``(n_rows, n_cols)`` (each in 1..256).
    :param start: start cell ``(row, col)``.
    :param goal: goal cell; reaching it gives +100 and terminates the episode.
    :param obstacles: blocked cells; moving into one gives -10 and the agent stays.
    :param max_steps: steps after which an unsuccessful episode is truncated (1..10**9).
    :param render_mode: ``"ansi"`` (returns the book's text grid), ``"human"`` (prints it)
        or ``"rgb_array"`` (an ``(H, W, 3)`` uint8 image, 32 pixels per cell).
    """

    metadata = {"render_modes": ["ansi", "human", "rgb_array"], "render_fps": 4}
    obs_names: tuple[str, ...] = ("cell",)
    action_names: tuple[str, ...] = ("move",)

    def __init__(
        self,
        size: int | Sequence[int] = 5,
        start: Sequence[int] = (0, 0),
        goal: Sequence[int] = (4, 4),
        obstacles: Iterable[Sequence[int]] = ((1, 1), (2, 2), (3, 3)),
        max_steps: int = 100,
        render_mode: str | None = None,
    ) -> None:
        sides = (size, size) if _is_int(size) else _int_pair(size, "size")
        n_rows, n_cols = (check_int(n, "size", 1, MAX_GRID_SIDE) for n in sides)
        self.n_rows, self.n_cols = n_rows, n_cols
        self.start = self._cell(start, "start")
        self.goal = self._cell(goal, "goal")
        if isinstance(obstacles, str) or not isinstance(obstacles, Iterable):
            raise ValueError(f"obstacles must be a list of (row, col) cells, got {obstacles!r}")
        self.obstacles = frozenset(self._cell(c, "obstacle") for c in obstacles)
        if self.start in self.obstacles or self.goal in self.obstacles:
            raise ValueError("start and goal must not be obstacles")
        max_steps = check_int(max_steps, "max_steps", 1, MAX_EPISODE_STEPS)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.max_steps = max_steps
        self.render_mode = render_mode
        self.observation_space = spaces.Discrete(n_rows * n_cols)
        self.action_space = spaces.Discrete(4)
        self.agent = self.start
        self.steps = 0

    def _cell(self, cell: Sequence[int], what: str) -> Cell:
        row, col = _int_pair(cell, what)
        if not (0 <= row < self.n_rows and 0 <= col < self.n_cols):
            raise ValueError(f"{what} {tuple(cell)} is outside the {self.n_rows}x{self.n_cols} grid")
        return row, col

    def to_obs(self, cell: Cell) -> np.int64:
        """Observation index of ``cell``: ``row * n_cols + col``."""
        return np.int64(cell[0] * self.n_cols + cell[1])

    def to_cell(self, obs: int) -> Cell:
        """Inverse of :meth:`to_obs`."""
        return int(obs) // self.n_cols, int(obs) % self.n_cols

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.int64, dict[str, Any]]:
        super().reset(seed=seed)
        self.agent = self.start
        self.steps = 0
        if self.render_mode == "human":
            self.render()
        return self.to_obs(self.agent), {}

    def step(self, action: Any) -> tuple[np.int64, float, bool, bool, dict[str, Any]]:
        if not self.action_space.contains(action):
            raise ValueError(f"action must be an int in 0..3 (up, down, left, right), got {action!r}")
        d_row, d_col = ACTION_DELTAS[int(action)]
        row, col = self.agent[0] + d_row, self.agent[1] + d_col
        event = "move"
        if not (0 <= row < self.n_rows and 0 <= col < self.n_cols):
            reward, event = WALL_REWARD, "wall"
        elif (row, col) in self.obstacles:
            reward, event = OBSTACLE_REWARD, "obstacle"
        else:
            self.agent = (row, col)
            reward = GOAL_REWARD if self.agent == self.goal else STEP_REWARD
        self.steps += 1
        terminated = self.agent == self.goal
        truncated = not terminated and self.steps >= self.max_steps
        info: dict[str, Any] = {"event": event}
        if terminated or truncated:
            info["is_success"] = terminated
        if self.render_mode == "human":
            self.render()
        return self.to_obs(self.agent), reward, terminated, truncated, info

    def grid_text(self, path: Iterable[Cell] = ()) -> str:
        """The book's text grid: ``A`` agent, ``G`` goal, ``X`` obstacle, ``*`` path, ``.`` free."""
        on_path = set(path)
        rows = []
        for r in range(self.n_rows):
            cells = []
            for c in range(self.n_cols):
                cell = (r, c)
                if cell == self.agent:
                    cells.append("A")
                elif cell == self.goal:
                    cells.append("G")
                elif cell in self.obstacles:
                    cells.append("X")
                elif cell in on_path:
                    cells.append("*")
                else:
                    cells.append(".")
            rows.append(" ".join(cells))
        return "\n".join(rows)

    def _rgb(self, cell_px: int = 32) -> np.ndarray:
        frame = np.full((self.n_rows * cell_px, self.n_cols * cell_px, 3), 255, dtype=np.uint8)
        for r, line in enumerate(self.grid_text().split("\n")):
            for c, symbol in enumerate(line.split(" ")):
                y, x = r * cell_px, c * cell_px
                frame[y + 1 : y + cell_px - 1, x + 1 : x + cell_px - 1] = _COLOURS[symbol]
        return frame
