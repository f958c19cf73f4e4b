"""Batched CooperativeTreasureHunt: the parameter-sharing VecEnv of ``n_envs`` teams, stepped as arrays.

Equivalent, step by step, to :class:`sbagents.multiagent.ParameterSharingVecEnv` over ``n_envs``
:class:`~sbagents.envs.treasure_hunt.CooperativeTreasureHunt` envs: slot ``k`` is agent ``k % n_agents`` of
env ``k // n_agents``; same ``float32`` observations (``book`` or ``egocentric``), rewards, dones, infos
(``treasures_collected`` and ``event`` every step; at episode end ``is_success``, ``terminal_observation``,
``TimeLimit.truncated`` in every slot of the env, and the team ``episode`` + ``treasures`` in its agent-0
slot), auto-reset, seeding (env ``i`` is reset with ``seed + i``), and one monitor file
``<monitor_dir>/0.monitor.csv`` with one row per team episode.

A step is one call of the compiled kernel :func:`sbagents.batched.kernels.treasure_step`: agents move in
index order (the lower index collects a treasure two agents step onto), and observations are assembled
from precomputed per-cell and per-cell-pair tables. Rewards are integers, so team returns summed in
any order equal the reference's exactly.

Each env copy owns a numpy ``Generator`` created exactly like the reference env's ``np_random``; resets
draw from it with the same call (one loop iteration per env that resets), so start states match the
reference.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from gymnasium.utils import seeding
from stable_baselines3.common.monitor import ResultsWriter
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn

from sbagents.batched.base import BatchedVecEnv
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
_EVENT_REWARD = np.array([STEP_REWARD, WALL_REWARD, OBSTACLE_REWARD, STEP_REWARD], dtype=np.float32)


class BatchedTreasureHuntVecEnv(BatchedVecEnv):
    """``n_envs`` treasure-hunt teams as one parameter-sharing SB3 ``VecEnv`` (``n_envs * n_agents`` slots).

    :param n_envs: number of env copies (teams).
    :param env_kwargs: keyword arguments of :class:`CooperativeTreasureHunt`.
    :param monitor_path: if given, team episodes are written to this SB3 monitor file
        (``r`` team return, ``l``, ``t``, ``treasures``), like the reference.

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
        self._dim = int(obs_space.shape[0])
        n, n_a, n_t = n_envs, self.n_agents, self.n_treasures
        self._cells = self.size * self.size  # cell index ``cells`` is the "collected" sentinel
        self._build_move_table(env)
        self._build_obs_tables(env)
        self._obs_tables = (self._coords, self._neighbours, self._book_tail, self._scale, self.egocentric)
        self._pos = np.zeros((n, n_a), dtype=np.int64)  # flat cells row * size + col
        self._treasure = np.zeros((n, n_t), dtype=np.int64)  # initial treasure cells
        self._tcell = np.zeros((n, n_t), dtype=np.int64)  # treasure cell, or the sentinel once collected
        self._collected = np.zeros(n, dtype=np.int64)
        self._ep_len = np.zeros(n, dtype=np.int64)
        self._ep_return = np.zeros(n, dtype=np.float64)  # team return
        self._rngs: list[np.random.Generator | None] = [None] * n
        super().__init__(n * n_a, n_a, env, obs_space, env.action_space(self.possible_agents[0]))
        self._writer: ResultsWriter | None = None
        if monitor_path is not None:
            header: dict[str, float | str] = {"t_start": self._t_start, "env_id": TREASURE_HUNT_ID}
            self._writer = ResultsWriter(monitor_path, header=header, extra_keys=("treasures",))

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
        self._event_names = np.array(EVENTS, dtype=object)

    def _build_obs_tables(self, env: CooperativeTreasureHunt) -> None:
        """Small tables the kernel builds observations from (as the reference computes them).

        ``_coords (cells + 1, 2)``: row/col of each cell, ``(-1, -1)`` for the collected sentinel;
        ``_neighbours (cells, 4)``: up/down/left/right is an edge or obstacle; ``_book_tail``: the book
        layout's obstacle coordinates; ``_scale = 1 / (grid_size - 1)``.
        """
        rows, cols = np.divmod(np.arange(self._cells + 1), self.size)
        self._coords = np.stack([rows, cols], axis=-1).astype(np.int64)
        self._coords[self._cells] = -1
        self._neighbours = (self._move[:, :4, 1] != 0).astype(np.float32)
        self._book_tail = np.array(env.obstacles, dtype=np.float32).reshape(-1)
        self._scale = 1.0 / (self.size - 1)

    # ------------------------------------------------------------------ reset
    def seed(self, seed: int | None = None) -> list[int | None]:  # type: ignore[override]
        """Env ``i`` (all its agent slots) is reset with ``seed + i`` at the next :meth:`reset`."""
        if seed is None:
            seed = int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
        self._seeds = [seed + k // self.n_agents for k in range(self.num_envs)]
        return self._seeds

    def _reset_envs(self, envs: list[int], obs: np.ndarray) -> None:
        """Reset the given env copies (per-env RNG draws, like the reference ``reset``); write their obs."""
        n_a, size, n_free = self.n_agents, self.size, len(self._free)
        n_picks = n_a + self.n_treasures
        seeds, options, rngs, reset_infos = self._seeds, self._options, self._rngs, self.reset_infos
        picks = np.empty((len(envs), n_picks), dtype=np.int64)  # indices into the free cells
        for q, i in enumerate(envs):
            first = i * n_a
            seed, rng = seeds[first], rngs[i]
            if seed is not None or rng is None:
                rng, _ = seeding.np_random(seed)
                rngs[i] = rng
                seeds[first : first + n_a] = [None] * n_a
            option = options[first]
            if option and ("agents" in option or "treasures" in option):
                self.template.reset(options=option)  # validates and places by hand (no RNG draw)
                placed = (*self.template.positions, *self.template.treasures)
                picks[q] = self._free_index[[r * size + c for r, c in placed]]
            else:
                picks[q] = rng.choice(n_free, n_picks, replace=False)
            for s in range(first, first + n_a):
                reset_infos[s] = {"treasures_collected": 0}
        treasure_reset(np.array(envs, dtype=np.int64), picks, self._free, self._pos, self._tcell, self._treasure,
                       self._collected, self._ep_len, self._ep_return, *self._obs_tables, self.max_cycles, obs)

    def reset(self) -> VecEnvObs:
        """Reset every env (pending seeds/options are used once); returns ``(num_envs, obs_dim)`` float32."""
        obs = np.zeros((self.n_envs, self.n_agents, self._dim), dtype=np.float32)
        self._reset_envs(list(range(self.n_envs)), obs)
        self._reset_options()
        return obs.reshape(self.num_envs, -1)

    # ------------------------------------------------------------------ step
    def step_wait(self) -> VecEnvStepReturn:
        acts = self._actions
        n, n_a, k = self.n_envs, self.n_agents, self.num_envs
        obs = np.zeros((n, n_a, self._dim), dtype=np.float32)
        rewards = np.empty(k, dtype=np.float32)
        events = np.empty(k, dtype=np.int64)
        slot_collected = np.empty(k, dtype=np.int64)
        dones = np.empty(n, dtype=bool)
        terminated = np.empty(n, dtype=bool)
        n_done = treasure_step(
            acts, self._pos, self._tcell, self._collected, self._ep_len, self._ep_return, self._move,
            _EVENT_REWARD, TREASURE_REWARD, self.shared, self.max_cycles, *self._obs_tables, obs, rewards, dones,
            terminated, events, slot_collected,
        )
        if n_done < 0:
            self._raise_invalid_action(-1 - n_done, self._n_actions)
        infos: list[dict[str, Any]] = [
            {"treasures_collected": c, "event": e}
            for c, e in zip(slot_collected.tolist(), self._event_names[events].tolist())  # noqa: B905 (same size)
        ]
        if n_done:
            ended = np.flatnonzero(dones).tolist()
            self._finish_episodes(ended, infos, terminated, obs)
            self._reset_envs(ended, obs)
        return obs.reshape(k, -1), rewards, dones.repeat(n_a), infos

    def _finish_episodes(
        self, ended: list[int], infos: list[dict[str, Any]], terminated: np.ndarray, obs: np.ndarray
    ) -> None:
        """Episode-end infos of the ``ended`` envs and their monitor rows (before ``obs`` is reset)."""
        n_a = self.n_agents
        terminal = list(obs[ended].reshape(-1, self._dim))  # copies: the reset rewrites these rows of ``obs``
        returns, lengths = self._ep_return[ended].tolist(), self._ep_len[ended].tolist()
        treasures, success = self._collected[ended].tolist(), terminated[ended].tolist()
        seconds = round(time.time() - self._t_start, 6)
        for q, i in enumerate(ended):
            term = success[q]
            for j in range(n_a):
                info = infos[i * n_a + j]
                info["is_success"] = term
                info["TimeLimit.truncated"] = not term
                info["terminal_observation"] = terminal[q * n_a + j]
            ep = {"r": round(returns[q], 6), "l": lengths[q], "t": seconds}
            infos[i * n_a]["episode"] = ep
            infos[i * n_a]["treasures"] = treasures[q]
            if self._writer is not None:
                self._writer.write_row({**ep, "treasures": treasures[q]})

    # ------------------------------------------------------------------ attributes / rendering
    def _sync(self, env_index: int) -> None:
        env, size = self.template, self.size
        env.positions = [divmod(int(c), size) for c in self._pos[env_index]]
        env.treasures = [divmod(int(c), size) for c in self._treasure[env_index]]
        env.present = [bool(c != self._cells) for c in self._tcell[env_index]]
        env.collected = int(self._collected[env_index])
        env.steps = int(self._ep_len[env_index])
        env.agents = list(self.possible_agents)

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        """Always False, as the reference (PettingZoo envs are never Gymnasium wrappers)."""
        return [False for _ in self._env_indices(indices)]

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """``human``/``ansi``: each env renders itself; ``rgb_array`` images of all envs are tiled."""
        if self.render_mode in ("human", "ansi"):
            for i in range(self.n_envs):
                self._sync(i)
                self.template.render()
            return None
        return super().render(mode)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None
