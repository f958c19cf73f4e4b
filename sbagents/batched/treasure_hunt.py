"""Batched CooperativeTreasureHunt: the parameter-sharing VecEnv of ``n_envs`` teams, stepped as arrays.

Equivalent, step by step, to :class:`sbagents.multiagent.parameter_sharing.ParameterSharingVecEnv` over ``n_envs``
:class:`~sbagents.envs.treasure_hunt.CooperativeTreasureHunt` envs: slot ``k`` is agent ``k % n_agents`` of
env ``k // n_agents``; same ``float32`` observations (``book`` or ``egocentric``), rewards, dones, infos
(``treasures_collected`` and ``event`` every step; at episode end ``is_success``, ``terminal_observation``,
``TimeLimit.truncated`` in every slot of the env, and the team ``episode`` (with the declared metric
``treasures_collected``) in its agent-0 slot), auto-reset, seeding (env ``i`` is reset with ``seed + i``), and
one monitor file ``<monitor_dir>/0.monitor.csv`` with one row per team episode.

A step is one call of the compiled kernel :func:`sbagents.batched.kernels.treasure_step`: agents move in
index order (the lower index collects a treasure two agents step onto), and observations are assembled
from small per-cell tables in one pass over all teams. Rewards are integers, so team returns summed in
any order equal the reference's exactly.

Each env copy owns a numpy ``Generator`` created exactly like the reference env's ``np_random`` and draws
its start states with the same call, so they match the reference. The generator serves only resets, so
each team's *next* start is drawn as soon as its current episode starts: the kernel then resets a finished
team in place, and Python only draws the following start (one ``choice`` call per finished episode).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.utils import seeding
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn

from sbagents.batched.base import BatchedTeamVecEnv
from sbagents.batched.kernels import treasure_reset, treasure_step
from sbagents.envs.treasure_hunt import (
    ACTION_DELTAS,
    OBSTACLE_REWARD,
    STEP_REWARD,
    TREASURE_REWARD,
    WALL_REWARD,
    CooperativeTreasureHunt,
)

TREASURE_HUNT_ID = "treasure_hunt_v0"
#: Event codes -> the reference env's ``info["event"]`` strings.
EVENTS: tuple[str, ...] = ("move", "wall", "obstacle", "treasure")
#: Rewards of the event codes, then the bonus per treasure collected.
_REWARD_OF = np.array([STEP_REWARD, WALL_REWARD, OBSTACLE_REWARD, STEP_REWARD, TREASURE_REWARD], dtype=np.float64)


class BatchedTreasureHuntVecEnv(BatchedTeamVecEnv):
    """``n_envs`` treasure-hunt teams as one parameter-sharing SB3 ``VecEnv`` (``n_envs * n_agents`` slots).

    :param n_envs: number of env copies (teams).
    :param env_kwargs: keyword arguments of :class:`CooperativeTreasureHunt`.
    :param monitor_path: if given, team episodes are written to this SB3 monitor file
        (``r`` team return, ``l``, ``t``, ``treasures_collected``), like the reference.

    Observations have shape ``(n_envs * n_agents, obs_dim)`` float32; actions ``(n_envs * n_agents,)``.
    """

    def __init__(
        self, n_envs: int, env_kwargs: dict[str, Any] | None = None, monitor_path: str | None = None
    ) -> None:
        if n_envs < 1:
            raise ValueError(f"n_envs must be >= 1, got {n_envs}")
        env = CooperativeTreasureHunt(**(env_kwargs or {}))
        self.possible_agents = list(env.possible_agents)
        self.n_agents, self.n_treasures, self.size = env.n_agents, env.n_treasures, env.grid_size
        self.max_cycles, self.shared = env.max_cycles, env.reward_mode == "shared"
        self.egocentric = env.observation_mode == "egocentric"
        obs_space = env.observation_space(self.possible_agents[0])
        assert obs_space.shape is not None  # a Box of shape (obs_dim,)
        self._dim = int(obs_space.shape[0])
        n, n_a, n_t = n_envs, self.n_agents, self.n_treasures
        self._cells = self.size * self.size  # cell index ``cells`` is the "collected" sentinel
        self._build_move_table(env)
        self._build_obs_tables(env)
        # packed state (see sbagents.batched.kernels): agent cells | treasure cells | initial treasure cells
        self._state = np.zeros((n, n_a + 2 * n_t), dtype=np.int64)
        self._pos, self._tcell = self._state[:, :n_a], self._state[:, n_a : n_a + n_t]
        self._treasure = self._state[:, n_a + n_t :]
        self._counters = np.zeros((n, 2), dtype=np.int64)  # treasures collected, episode length
        self._returns = np.zeros(n, dtype=np.float64)  # team return
        self._next_picks = np.zeros((n, n_a + n_t), dtype=np.int64)  # next start: indices into free cells
        self._finals = np.zeros((4, n), dtype=np.int64)  # kernel output: ended team, length, treasures, success
        self._final_returns = np.zeros(n, dtype=np.float64)
        self._terminal = np.zeros((n, n_a, self._dim), dtype=np.float32)
        self._rngs: list[np.random.Generator | None] = [None] * n
        super().__init__(n * n_a, n_a, env, obs_space, env.action_space(self.possible_agents[0]), monitor_path,
                         TREASURE_HUNT_ID, ("treasures_collected",))

    # ------------------------------------------------------------------ tables
    def _build_move_table(self, env: CooperativeTreasureHunt) -> None:
        """``move (cells, n_actions, 2)``: next cell and event code (0 move, 1 wall, 2 obstacle)."""
        size, cells = self.size, self._cells
        blocked = np.zeros(cells, dtype=bool)
        for r, c in env.obstacles:
            blocked[r * size + c] = True
        self._free = np.flatnonzero(~blocked)  # row-major, as the reference's free-cell list
        self._free_index = np.full(cells, -1, dtype=np.int64)
        self._free_index[self._free] = np.arange(len(self._free))
        self._n_actions = len(ACTION_DELTAS)
        move = np.zeros((cells, self._n_actions, 2), dtype=np.int64)
        for cell in range(cells):
            r, c = divmod(cell, size)
            for a, (dr, dc) in enumerate(ACTION_DELTAS):
                rr, cc = r + dr, c + dc
                if not (0 <= rr < size and 0 <= cc < size):
                    move[cell, a] = (cell, 1)
                elif blocked[rr * size + cc]:
                    move[cell, a] = (cell, 2)
                else:
                    move[cell, a] = (rr * size + cc, 0)
        self._move = move

    def _build_obs_tables(self, env: CooperativeTreasureHunt) -> None:
        """Small tables the kernel builds observations from (values computed as the reference does).

        ``coords (cells + 1, 2)``: row/col of each cell, ``(-1, -1)`` for the collected sentinel;
        ``neighbours (cells, 4)``: up/down/left/right is an edge or obstacle; ``book_tail``: the book
        layout's obstacle coordinates; ``offs[d + size - 1]`` = float32 of ``d / (size - 1)``.
        """
        rows, cols = np.divmod(np.arange(self._cells + 1), self.size)
        coords = np.stack([rows, cols], axis=-1).astype(np.int64)
        coords[self._cells] = -1
        neighbours = (self._move[:, :4, 1] != 0).astype(np.float32)
        book_tail = np.array(env.obstacles, dtype=np.float32).reshape(-1)
        offs = (np.arange(-(self.size - 1), self.size) * (1.0 / (self.size - 1))).astype(np.float32)
        params = np.array([self.shared, self.max_cycles, self.egocentric], dtype=np.int64)
        self._tables = (self._move, _REWARD_OF, params, coords, neighbours, book_tail, offs, self._free)

    # ------------------------------------------------------------------ reset
    def _draw(self, rng: np.random.Generator) -> np.ndarray:
        """A start state as the reference draws it: free-cell indices of the agents, then the treasures."""
        return rng.choice(len(self._free), self.n_agents + self.n_treasures, replace=False)

    def reset(self) -> VecEnvObs:
        """Reset every env (pending seeds/options are used once); returns ``(num_envs, obs_dim)`` float32."""
        n_a, size = self.n_agents, self.size
        picks = np.empty_like(self._next_picks)
        for i in range(self.n_envs):
            seed, option, rng = self._seeds[i * n_a], self._options[i * n_a], self._rngs[i]
            if seed is not None or rng is None:  # a new generator: its first draw is this reset's
                rng, _ = seeding.np_random(seed)
                self._rngs[i] = rng
                self._next_picks[i] = self._draw(rng)
            if option and ("agents" in option or "treasures" in option):
                self.template.reset(options=option)  # validates and places by hand (no RNG draw)
                placed = (*self.template.positions, *self.template.treasures)
                picks[i] = self._free_index[[r * size + c for r, c in placed]]
            else:  # the pre-drawn start, then the generator's next draw for the following episode
                picks[i] = self._next_picks[i]
                self._next_picks[i] = self._draw(rng)
        self.reset_infos = [{"treasures_collected": 0} for _ in range(self.num_envs)]
        self._reset_seeds()
        self._reset_options()
        obs = np.zeros((self.n_envs, n_a, self._dim), dtype=np.float32)
        _, _, params, coords, neighbours, book_tail, offs, free = self._tables
        treasure_reset(picks, free, self._state, self._counters, self._returns, params, coords, neighbours,
                       book_tail, offs, obs)
        return obs.reshape(self.num_envs, -1)

    # ------------------------------------------------------------------ step
    def step_wait(self) -> VecEnvStepReturn:
        n, n_a, k = self.n_envs, self.n_agents, self.num_envs
        obs = np.zeros((n, n_a, self._dim), dtype=np.float32)
        rewards = np.empty(k, dtype=np.float32)
        flags = np.empty((2, n), dtype=bool)  # done, terminated
        slot_info = np.empty((2, k), dtype=np.int64)  # event code, treasures collected
        move, reward_of, params, coords, neighbours, book_tail, offs, free = self._tables
        n_done = treasure_step(
            self._actions, self._state, self._counters, self._returns, move, reward_of, params, coords,
            neighbours, book_tail, offs, free, self._next_picks, obs, rewards, flags, slot_info, self._finals,
            self._final_returns, self._terminal,
        )
        if n_done < 0:
            self._raise_invalid_action(-1 - n_done, self._n_actions)
        events, collected = slot_info.tolist()
        names = EVENTS
        infos: list[dict[str, Any]] = [
            {"treasures_collected": c, "event": names[e]} for e, c in zip(events, collected)  # noqa: B905
        ]
        if n_done:
            self._finish_episodes(n_done, infos)
        return obs.reshape(k, -1), rewards, flags[0].repeat(n_a), infos

    def _finish_episodes(self, n_done: int, infos: list[dict[str, Any]]) -> None:
        """Episode-end infos and monitor rows of the ``n_done`` teams the kernel reset; draw their next starts."""
        n_a = self.n_agents
        ended, lengths, treasures, success = self._finals[:, :n_done].tolist()
        returns = self._final_returns[:n_done].tolist()
        terminal = list(self._terminal[:n_done].reshape(-1, self._dim).copy())  # rows, one per slot
        seconds = self._monitor_seconds()
        for q, i in enumerate(ended):
            term = success[q] == 1
            first = i * n_a
            for j in range(n_a):
                info = infos[first + j]
                info["is_success"] = term
                info["TimeLimit.truncated"] = not term
                info["terminal_observation"] = terminal[q * n_a + j]
                self.reset_infos[first + j] = {"treasures_collected": 0}
            ep = {"r": round(returns[q], 6), "l": lengths[q], "t": seconds, "treasures_collected": treasures[q]}
            infos[first]["episode"] = ep
            if self._writer is not None:
                self._writer.write_row(ep)
            self._next_picks[i] = self._draw(self._rngs[i])  # type: ignore[arg-type]

    # ------------------------------------------------------------------ attributes / rendering
    def _sync(self, env_index: int) -> None:
        env, size = self.template, self.size
        env.positions = [divmod(int(c), size) for c in self._pos[env_index]]
        env.treasures = [divmod(int(c), size) for c in self._treasure[env_index]]
        env.present = [bool(c != self._cells) for c in self._tcell[env_index]]
        env.collected = int(self._counters[env_index, 0])
        env.steps = int(self._counters[env_index, 1])
        env.agents = list(self.possible_agents)

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """``human``/``ansi``: each env renders itself; ``rgb_array`` images of all envs are tiled."""
        if self.render_mode in ("human", "ansi"):
            for i in range(self.n_envs):
                self._sync(i)
                self.template.render()
            return None
        return super().render(mode)
