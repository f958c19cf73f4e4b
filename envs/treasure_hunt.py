"""CooperativeTreasureHunt from chapter 4 of the book, as a PettingZoo ``ParallelEnv``.

Spec (docs/envs.md, CooperativeTreasureHunt): a 10x10 grid, agents ``agent_0 .. agent_{n-1}`` (3 by default),
5 treasures, 10 fixed obstacles. Actions ``Discrete(5)``: 0 up (row-1), 1 down (row+1), 2 left (col-1),
3 right (col+1), 4 stay. Agents move in index order within a step. Rewards per agent and step:

- off-grid move: -1, the agent stays; move into an obstacle: -5, the agent stays;
- otherwise the agent moves (staying counts as a move) and gets -1;
- moving onto a treasure collects it: +10 to *every* agent's reward that step (``reward_mode="shared"``,
  the book) or only to the collector (``reward_mode="individual"``, the book's competitive exercise).

Agents may share a cell. The episode terminates when every treasure is collected and is truncated
after ``max_cycles`` steps (50). Agents and treasures start on distinct random free cells each episode,
drawn from ``self.np_random`` (seeded by ``reset(seed=...)``).

Observations (``float32``, fixed size, the same space for every agent):

- ``"book"``: own ``(row, col)``, then every treasure's ``(row, col)`` in their initial order, then every
  obstacle's ``(row, col)``; a collected treasure is marked with the sentinel ``(-1, -1)``
  (``2 + 2 * n_treasures + 2 * n_obstacles`` numbers, 32 by default; raw grid coordinates).
- ``"egocentric"`` (agent-centred, meant for parameter sharing), all in ``[-1, 1]``:
  one-hot agent id (``n_agents``); own position ``/ (size - 1)`` (2); remaining time fraction (1);
  for each treasure slot, sorted by Manhattan distance with collected treasures last:
  ``present, d_row / (size - 1), d_col / (size - 1)`` (3 per treasure, zeros when collected);
  the other agents' offsets in index order (2 each); and whether each of the four neighbouring cells
  (up, down, left, right) is blocked by the grid edge or an obstacle (4).

Deviations from the book (documented in the README table): the observation has a fixed size (the
book's shrinks when a treasure is collected), the agent list is created before reset reads it, and the
egocentric observation and the reward mode are additions.

Hand-built states for tests: ``reset(options={"agents": [(r, c), ...], "treasures": [(r, c), ...]})``
places the agents and treasures exactly there (cells must be free of obstacles; treasures distinct).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from sbagents.envs.bounds import MAX_EPISODE_STEPS, MAX_GRID_SIDE, check_int
from sbagents.envs.text_grid import TextGridRendering

Cell = tuple[int, int]

#: Row/column deltas of the actions: 0 up, 1 down, 2 left, 3 right, 4 stay.
ACTION_DELTAS: tuple[Cell, ...] = ((-1, 0), (1, 0), (0, -1), (0, 1), (0, 0))
MOVE_NAMES: tuple[str, ...] = ("up", "down", "left", "right", "stay")
DEFAULT_OBSTACLES: tuple[Cell, ...] = (
    (2, 2), (3, 3), (4, 4), (5, 5), (6, 6), (2, 7), (7, 2), (3, 8), (8, 3), (5, 7),
)  # fmt: skip

STEP_REWARD = -1.0
WALL_REWARD = -1.0
OBSTACLE_REWARD = -5.0
TREASURE_REWARD = 10.0

REWARD_MODES = ("shared", "individual")
RENDER_MODES = ("human", "ansi", "rgb_array")
OBSERVATION_MODES = ("book", "egocentric")
#: Keyword arguments accepted by the constructor (the CLI reports them on a typo).
ACCEPTED_KWARGS: tuple[str, ...] = (
    "grid_size",
    "n_agents",
    "n_treasures",
    "obstacles",
    "max_cycles",
    "reward_mode",
    "observation",
    "render_mode",
)

#: The most agents and treasures an env takes (observations grow with both; the book has 3 and 5).
MAX_AGENTS = 64
MAX_TREASURES = 256

_COLOURS = {"A": (30, 110, 230), "T": (230, 180, 20), "X": (60, 60, 60), ".": (235, 235, 235)}


class CooperativeTreasureHunt(TextGridRendering, ParallelEnv):
    """Cooperative multi-agent treasure collection on a grid with obstacles.

    :param grid_size: side length of the square grid (2..256).
    :param n_agents: number of agents ``agent_0 .. agent_{n-1}`` (1..64).
    :param n_treasures: treasures placed each episode (1..256).
    :param obstacles: blocked cells ``(row, col)``; default the book's 10 cells.
    :param max_cycles: steps after which the episode is truncated (1..10**9).
    :param reward_mode: ``"shared"`` (every agent gets +10 per treasure) or ``"individual"``.
    :param observation: ``"book"`` (absolute layout) or ``"egocentric"`` (offsets + agent id).
    :param render_mode: ``"ansi"`` (text grid), ``"human"`` (prints it) or ``"rgb_array"``
        (``(H, W, 3)`` uint8, 32 pixels per cell).
    """

    metadata = {
        "name": "treasure_hunt_v0",
        "render_modes": ["human", "ansi", "rgb_array"],
        "render_fps": 4,
        "is_parallelizable": True,
        "info_metrics": {"treasures_collected": "last"},  # episode metric: treasures collected by the team
    }
    action_names: tuple[str, ...] = ("move",)

    def __init__(
        self,
        grid_size: int = 10,
        n_agents: int = 3,
        n_treasures: int = 5,
        obstacles: Iterable[Sequence[int]] = DEFAULT_OBSTACLES,
        max_cycles: int = 50,
        reward_mode: str = "shared",
        observation: str = "book",
        render_mode: str | None = None,
    ) -> None:
        self.grid_size = check_int(grid_size, "grid_size", 2, MAX_GRID_SIDE)
        n_agents = check_int(n_agents, "n_agents", 1, MAX_AGENTS)
        n_treasures = check_int(n_treasures, "n_treasures", 1, MAX_TREASURES)
        if isinstance(obstacles, str) or not isinstance(obstacles, Iterable):
            raise ValueError(f"obstacles must be a list of (row, col) cells, got {obstacles!r}")
        self.obstacles: tuple[Cell, ...] = tuple(self._cell(c, "obstacle") for c in obstacles)
        self._blocked = frozenset(self.obstacles)
        n_free = self.grid_size**2 - len(self._blocked)
        if n_agents < 1 or n_treasures < 1 or n_agents + n_treasures > n_free:
            raise ValueError(
                f"need n_agents >= 1, n_treasures >= 1 and n_agents + n_treasures <= {n_free} free cells, "
                f"got n_agents={n_agents}, n_treasures={n_treasures}"
            )
        max_cycles = check_int(max_cycles, "max_cycles", 1, MAX_EPISODE_STEPS)
        if reward_mode not in REWARD_MODES:
            raise ValueError(f"reward_mode must be one of {REWARD_MODES}, got {reward_mode!r}")
        if observation not in OBSERVATION_MODES:
            raise ValueError(f"observation must be one of {OBSERVATION_MODES}, got {observation!r}")
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be one of {RENDER_MODES}, got {render_mode!r}")
        self.n_agents, self.n_treasures = int(n_agents), int(n_treasures)
        self.max_cycles = int(max_cycles)
        self.reward_mode, self.observation_mode, self.render_mode = reward_mode, observation, render_mode
        self.possible_agents = [f"agent_{i}" for i in range(self.n_agents)]
        self.agents = list(self.possible_agents)
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        self.obs_names = self._make_obs_names()
        size = len(self.obs_names)
        if observation == "book":
            space = spaces.Box(-1.0, float(self.grid_size - 1), (size,), np.float32)
        else:
            space = spaces.Box(-1.0, 1.0, (size,), np.float32)
        self.observation_spaces = {a: space for a in self.possible_agents}
        self.action_spaces: dict[str, spaces.Space[Any]] = {
            a: spaces.Discrete(len(ACTION_DELTAS)) for a in self.possible_agents
        }
        self._free = [
            (r, c)
            for r in range(self.grid_size)
            for c in range(self.grid_size)
            if (r, c) not in self._blocked
        ]
        self.positions: list[Cell] = []
        self.treasures: list[Cell] = []
        self.present: list[bool] = []
        self.collected = 0
        self.steps = 0
        self._np_random: np.random.Generator | None = None
        if observation == "egocentric":
            self._neighbours = self._neighbour_table()

    def _cell(self, cell: Sequence[int], what: str) -> Cell:
        row, col = int(cell[0]), int(cell[1])
        if not (0 <= row < self.grid_size and 0 <= col < self.grid_size):
            raise ValueError(f"{what} {tuple(cell)} is outside the {self.grid_size}x{self.grid_size} grid")
        return row, col

    def _make_obs_names(self) -> tuple[str, ...]:
        if self.observation_mode == "book":
            names = ["row", "col"]
            for i in range(self.n_treasures):
                names += [f"treasure{i}_row", f"treasure{i}_col"]
            for i in range(len(self.obstacles)):
                names += [f"obstacle{i}_row", f"obstacle{i}_col"]
            return tuple(names)
        names = [f"id_{i}" for i in range(self.n_agents)] + ["row", "col", "time_left"]
        for k in range(self.n_treasures):
            names += [f"near{k}_present", f"near{k}_drow", f"near{k}_dcol"]
        for k in range(self.n_agents - 1):
            names += [f"other{k}_drow", f"other{k}_dcol"]
        return tuple(names + [f"blocked_{m}" for m in MOVE_NAMES[:4]])

    def _neighbour_table(self) -> dict[Cell, list[float]]:
        table: dict[Cell, list[float]] = {}
        n = self.grid_size
        for r in range(n):
            for c in range(n):
                flags = []
                for dr, dc in ACTION_DELTAS[:4]:
                    rr, cc = r + dr, c + dc
                    flags.append(float(not (0 <= rr < n and 0 <= cc < n) or (rr, cc) in self._blocked))
                table[(r, c)] = flags
        return table

    @property
    def np_random(self) -> np.random.Generator:
        """The env's random generator (seeded by ``reset(seed=...)``; the only source of randomness)."""
        if self._np_random is None:
            self._np_random, _ = seeding.np_random(None)
        return self._np_random

    def observation_space(self, agent: str) -> spaces.Space:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Space:
        return self.action_spaces[agent]

    # ------------------------------------------------------------------ reset / step
    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        if seed is not None or self._np_random is None:
            self._np_random, _ = seeding.np_random(seed)
        options = options or {}
        if "agents" in options or "treasures" in options:
            self._place_by_hand(options)
        else:
            picks = self.np_random.choice(len(self._free), self.n_agents + self.n_treasures, replace=False)
            cells = [self._free[int(i)] for i in picks]
            self.positions = cells[: self.n_agents]
            self.treasures = cells[self.n_agents :]
        self.present = [True] * self.n_treasures
        self.collected = 0
        self.steps = 0
        self.agents = list(self.possible_agents)
        if self.render_mode == "human":
            self.render()
        infos = {a: {"treasures_collected": 0} for a in self.agents}
        return self._observations(), infos

    def _place_by_hand(self, options: dict[str, Any]) -> None:
        agents = [self._cell(c, "agent") for c in options.get("agents", ())]
        treasures = [self._cell(c, "treasure") for c in options.get("treasures", ())]
        if len(agents) != self.n_agents or len(treasures) != self.n_treasures:
            raise ValueError(
                f"options need {self.n_agents} 'agents' cells and {self.n_treasures} 'treasures' cells"
            )
        if any(c in self._blocked for c in agents + treasures) or len(set(treasures)) != len(treasures):
            raise ValueError("hand-placed agents/treasures must be on free cells, treasures distinct")
        self.positions, self.treasures = agents, treasures

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[
        dict[str, np.ndarray], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict[str, Any]]
    ]:
        self._check_actions(actions)
        n = self.grid_size
        rewards = [0.0] * self.n_agents
        found = [0] * self.n_agents  # treasures collected by each agent this step
        events = [""] * self.n_agents
        for i, agent in enumerate(self.possible_agents):
            dr, dc = ACTION_DELTAS[int(actions[agent])]
            r, c = self.positions[i]
            rr, cc = r + dr, c + dc
            if not (0 <= rr < n and 0 <= cc < n):
                rewards[i], events[i] = WALL_REWARD, "wall"
                continue
            if (rr, cc) in self._blocked:
                rewards[i], events[i] = OBSTACLE_REWARD, "obstacle"
                continue
            self.positions[i] = (rr, cc)
            rewards[i], events[i] = STEP_REWARD, "move"
            for k, cell in enumerate(self.treasures):
                if self.present[k] and cell == (rr, cc):
                    self.present[k] = False
                    found[i] += 1
                    events[i] = "treasure"
        self.collected += sum(found)
        if self.reward_mode == "shared":
            rewards = [x + TREASURE_REWARD * sum(found) for x in rewards]
        else:
            rewards = [x + TREASURE_REWARD * f for x, f in zip(rewards, found, strict=True)]
        self.steps += 1
        terminated = self.collected == self.n_treasures
        truncated = not terminated and self.steps >= self.max_cycles
        agents = self.possible_agents
        obs = self._observations()
        infos: dict[str, dict[str, Any]] = {}
        for i, a in enumerate(agents):
            info: dict[str, Any] = {"treasures_collected": self.collected, "event": events[i]}
            if terminated or truncated:
                info["is_success"] = terminated
            infos[a] = info
        reward_d = {a: rewards[i] for i, a in enumerate(agents)}
        term_d = dict.fromkeys(agents, terminated)
        trunc_d = dict.fromkeys(agents, truncated)
        if terminated or truncated:
            self.agents = []
        if self.render_mode == "human":
            self.render()
        return obs, reward_d, term_d, trunc_d, infos

    def _check_actions(self, actions: dict[str, Any]) -> None:
        if not self.agents:
            raise ValueError("the episode is over: call reset() before step()")
        unknown = [a for a in actions if a not in self._index]
        if unknown:
            raise ValueError(f"actions for unknown agent(s) {unknown}; agents are {self.agents}")
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise ValueError(f"missing actions for agent(s) {missing}")
        for agent, action in actions.items():
            try:
                ok = int(action) == action and 0 <= int(action) < len(ACTION_DELTAS)
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise ValueError(
                    f"action for {agent} must be an int in 0..4 ({', '.join(MOVE_NAMES)}), got {action!r}"
                )

    # ------------------------------------------------------------------ observations
    def _observations(self) -> dict[str, np.ndarray]:
        if self.observation_mode == "book":
            return self._book_obs()
        return self._egocentric_obs()

    def _book_obs(self) -> dict[str, np.ndarray]:
        tail: list[float] = []
        for k, (r, c) in enumerate(self.treasures):
            tail += [float(r), float(c)] if self.present[k] else [-1.0, -1.0]
        for r, c in self.obstacles:
            tail += [float(r), float(c)]
        return {
            a: np.array([float(self.positions[i][0]), float(self.positions[i][1]), *tail], dtype=np.float32)
            for i, a in enumerate(self.possible_agents)
        }

    def _egocentric_obs(self) -> dict[str, np.ndarray]:
        scale = 1.0 / (self.grid_size - 1)
        time_left = 1.0 - self.steps / self.max_cycles
        left = [t for k, t in enumerate(self.treasures) if self.present[k]]
        pad = [0.0] * (3 * (self.n_treasures - len(left)))
        out = {}
        for i, a in enumerate(self.possible_agents):
            r, c = self.positions[i]
            vec = [0.0] * self.n_agents
            vec[i] = 1.0
            vec += [r * scale, c * scale, time_left]
            offsets = sorted(((tr - r, tc - c) for tr, tc in left), key=lambda d: abs(d[0]) + abs(d[1]))
            for dr, dc in offsets:
                vec += [1.0, dr * scale, dc * scale]
            vec += pad
            for j, (orow, ocol) in enumerate(self.positions):
                if j != i:
                    vec += [(orow - r) * scale, (ocol - c) * scale]
            vec += self._neighbours[(r, c)]
            out[a] = np.array(vec, dtype=np.float32)
        return out

    def observe(self, agent: str) -> np.ndarray:
        """Current observation of one agent (shape of its observation space)."""
        return self._observations()[agent]

    def state(self) -> np.ndarray:
        """Global state: agent cells, treasure cells (``-1`` when collected), step count; float32."""
        vals = [float(x) for p in self.positions for x in p]
        for k, (r, c) in enumerate(self.treasures):
            vals += [float(r), float(c)] if self.present[k] else [-1.0, -1.0]
        return np.array(vals + [float(self.steps)], dtype=np.float32)

    # ------------------------------------------------------------------ rendering
    def grid_text(self) -> str:
        """The book's text grid: ``A0``.. agents (lowest index on a shared cell), ``T`` treasure,
        ``X`` obstacle, ``.`` free; cells two characters wide, separated by spaces."""
        rows = []
        for r in range(self.grid_size):
            cells = []
            for c in range(self.grid_size):
                cells.append(self._symbol((r, c)).ljust(2))
            rows.append(" ".join(cells).rstrip())
        return "\n".join(rows)

    def _symbol(self, cell: Cell) -> str:
        for i, p in enumerate(self.positions):
            if p == cell:
                return f"A{i}"
        if any(self.present[k] and t == cell for k, t in enumerate(self.treasures)):
            return "T"
        return "X" if cell in self._blocked else "."

    def _rgb(self, cell_px: int = 32) -> np.ndarray:
        n = self.grid_size
        frame = np.full((n * cell_px, n * cell_px, 3), 255, dtype=np.uint8)
        for r in range(n):
            for c in range(n):
                symbol = self._symbol((r, c))[0] if self.positions else "."
                y, x = r * cell_px, c * cell_px
                frame[y + 1 : y + cell_px - 1, x + 1 : x + cell_px - 1] = _COLOURS[symbol]
        return frame
