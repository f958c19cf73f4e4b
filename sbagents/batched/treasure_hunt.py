"""Batched CooperativeTreasureHunt: the parameter-sharing VecEnv of ``n_envs`` teams, stepped as arrays.

Equivalent, step by step, to :class:`sbagents.multiagent.ParameterSharingVecEnv` over ``n_envs``
:class:`~sbagents.envs.treasure_hunt.CooperativeTreasureHunt` envs: slot ``k`` is agent ``k % n_agents`` of
env ``k // n_agents``; same ``float32`` observations (``book`` or ``egocentric``), rewards, dones, infos
(``treasures_collected`` and ``event`` every step; at episode end ``is_success``, ``terminal_observation``,
``TimeLimit.truncated`` in every slot of the env, and the team ``episode`` + ``treasures`` in its agent-0
slot), auto-reset, seeding (env ``i`` is reset with ``seed + i``), and one monitor file
``<monitor_dir>/0.monitor.csv`` with one row per team episode.

Agents move in index order within a step. Agents never block each other, so all moves are computed at
once; the order only matters when two agents of one env step onto the same treasure in the same step:
the lower index collects it (resolved with a stable de-duplication, no loop over envs or agents).
Observations come from precomputed per-cell and per-cell-pair tables; the egocentric "nearest
treasures" order is one stable sort of all (env, agent, treasure) keys. Rewards are integers, so team
returns summed per slot equal the reference's per-step team sums exactly.

Each env copy owns a numpy ``Generator`` created exactly like the reference env's ``np_random``; resets
draw from it with the same call (one loop iteration per env that resets), so start states match the
reference.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.utils import seeding
from stable_baselines3.common.monitor import ResultsWriter
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn

from sbagents.batched.base import BatchedVecEnv
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
_TREASURE = 3


def _rows_as_items(table: np.ndarray) -> np.ndarray:
    """View a C-contiguous 2-D table as a 1-D array with one (void) element per row (fast gathers)."""
    table = np.ascontiguousarray(table)
    return table.view(np.dtype((np.void, table.shape[1] * table.itemsize))).reshape(-1)


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
        self._cells = self.size * self.size  # cell index ``cells`` is the "no cell" sentinel
        self._build_move_tables(env)
        self._build_obs_tables(env, n)
        self._pos = np.zeros((n, n_a), dtype=np.int64)  # flat cells row * size + col
        self._treasure = np.zeros((n, n_t), dtype=np.int64)  # initial treasure cells
        self._tcell = np.zeros((n, n_t), dtype=np.int64)  # treasure cell, or the sentinel once collected
        self._tgrid = np.zeros(n * (self._cells + 1), dtype=bool)  # (env, cell) holds a present treasure
        self._tid = np.zeros(n * (self._cells + 1), dtype=np.int64)  # (env, cell) -> treasure index
        self._env_off = np.arange(n, dtype=np.int64) * (self._cells + 1)
        self._collected = np.zeros(n, dtype=np.int64)
        self._slot_env = np.repeat(np.arange(n, dtype=np.int64), n_a)  # slot -> env copy
        self._bonus = (TREASURE_REWARD * np.arange(n_a + 1)).astype(np.float32)  # reward for k treasures
        self._slot_collected: list[int] = [0] * (n * n_a)
        self._tick = 0  # steps since creation; an episode's step count is tick - start tick
        self._start_tick = np.zeros(n, dtype=np.int64)
        self._next_truncation = self.max_cycles  # earliest tick at which some episode is truncated
        self._no_dones = np.zeros(n, dtype=bool)
        self._slot_return = np.zeros((n, n_a), dtype=np.float64)
        self._rngs: list[np.random.Generator | None] = [None] * n
        self._obs = np.zeros((n, n_a, self._dim), dtype=np.float32)
        super().__init__(n * n_a, n_a, env, obs_space, env.action_space(self.possible_agents[0]))
        self._writer: ResultsWriter | None = None
        if monitor_path is not None:
            header: dict[str, float | str] = {"t_start": self._t_start, "env_id": TREASURE_HUNT_ID}
            self._writer = ResultsWriter(monitor_path, header=header, extra_keys=("treasures",))

    # ------------------------------------------------------------------ tables
    def _build_move_tables(self, env: CooperativeTreasureHunt) -> None:
        """``(cell, action)`` -> next cell, collecting cell (sentinel unless the agent moved), event code."""
        size, cells = self.size, self._cells
        self._blocked = np.zeros(cells, dtype=bool)
        for r, c in env.obstacles:
            self._blocked[r * size + c] = True
        self._free = np.flatnonzero(~self._blocked)  # row-major, as the reference's free-cell list
        self._free_index = np.full(cells, -1, dtype=np.int64)
        self._free_index[self._free] = np.arange(len(self._free))
        self._n_actions = len(ACTION_DELTAS)
        table = np.zeros((cells, self._n_actions, 3), dtype=np.int64)
        for cell in range(cells):
            r, c = divmod(cell, size)
            for a, (dr, dc) in enumerate(ACTION_DELTAS):
                rr, cc = r + dr, c + dc
                if not (0 <= rr < size and 0 <= cc < size):
                    table[cell, a] = (cell, cells, 1)
                elif self._blocked[rr * size + cc]:
                    table[cell, a] = (cell, cells, 2)
                else:
                    table[cell, a] = (rr * size + cc, rr * size + cc, 0)
        self._move = table
        self._event_names = np.array(EVENTS, dtype=object)

    def _build_obs_tables(self, env: CooperativeTreasureHunt, n_envs: int) -> None:
        """Per-cell and per-(agent cell, other cell) observation pieces, computed as the reference does.

        Tables are stored as one numpy element per row (``void``/``complex`` views), which makes the
        per-step gathers 1-D copies.
        """
        size, cells, n_a, n_t, dim = self.size, self._cells, self.n_agents, self.n_treasures, self._dim
        rows, cols = np.divmod(np.arange(cells + 1), size)
        self._others = np.array([[j for j in range(n_a) if j != i] for i in range(n_a)], dtype=np.int64)
        self._agent_off = np.arange(n_a, dtype=np.int64) * cells
        self_tab = np.zeros((n_a, cells, dim), dtype=np.float64)
        if self.egocentric:
            scale = 1.0 / (size - 1)
            self_tab[:, :, :n_a] = np.eye(n_a)[:, None, :]
            self_tab[:, :, n_a], self_tab[:, :, n_a + 1] = rows[:cells] * scale, cols[:cells] * scale
            self_tab[:, :, dim - 4 :] = self._move[:, :4, 2] != 0  # up/down/left/right: edge or obstacle
        else:
            self_tab[:, :, 0], self_tab[:, :, 1] = rows[:cells], cols[:cells]
            self_tab[:, :, 2 + 2 * n_t :] = np.array(env.obstacles, dtype=np.float64).reshape(-1)
            coord = np.stack([rows, cols], axis=-1).astype(np.float32)
            coord[cells] = -1.0  # collected treasure sentinel (-1, -1)
            self._tcoord = coord.view(np.float64).reshape(-1)  # one 8-byte element per cell
        self._self_tab = _rows_as_items(self_tab.astype(np.float32).reshape(n_a * cells, dim))
        if not self.egocentric:
            return
        self._time_left = (1.0 - np.arange(self.max_cycles + 1) / self.max_cycles).astype(np.float32)
        # (agent cell, other cell) pairs; other cell ``cells`` = collected treasure; padded to 2**k pairs
        self._pair_bits = int(cells * (cells + 1) - 1).bit_length()
        n_pairs = 1 << self._pair_bits
        d_row = (rows[None, :] - rows[:cells, None]).reshape(-1)
        d_col = (cols[None, :] - cols[:cells, None]).reshape(-1)
        present = np.ones((cells, cells + 1), dtype=bool)
        present[:, cells] = False
        present = present.reshape(-1)
        rel = np.zeros((n_pairs, 4), dtype=np.float64)  # present, d_row / (size-1), d_col / (size-1), pad
        rel[: len(present), 0] = present
        rel[: len(present), 1] = np.where(present, d_row * scale, 0.0)
        rel[: len(present), 2] = np.where(present, d_col * scale, 0.0)
        self._rel3 = _rows_as_items(rel[:, :3].astype(np.float32))
        self._pair_mask = n_pairs - 1
        self._rel2 = np.ascontiguousarray(rel[:, 1:3].astype(np.float32)).view(np.float64).reshape(-1)
        # sort key = row * stride + distance (collected: past any distance) + treasure index + pair index
        dist = np.full(n_pairs, 2 * size, dtype=np.int64)
        dist[: len(present)] = np.where(present, np.abs(d_row) + np.abs(d_col), 2 * size)
        per_dist = n_t * n_pairs
        self._dist_key = dist * per_dist + np.arange(n_pairs)
        row_stride = (2 * size + 1) * per_dist
        if row_stride * 2 * n_envs * n_a >= np.iinfo(np.int64).max:
            raise ValueError("grid too large for the batched egocentric observation")
        rows_k = np.arange(2 * n_envs * n_a, dtype=np.int64).reshape(2 * n_envs, n_a, 1) * row_stride
        self._row_key = rows_k + np.arange(n_t, dtype=np.int64) * n_pairs

    # ------------------------------------------------------------------ reset
    def seed(self, seed: int | None = None) -> list[int | None]:  # type: ignore[override]
        """Env ``i`` (all its agent slots) is reset with ``seed + i`` at the next :meth:`reset`."""
        if seed is None:
            seed = int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
        self._seeds = [seed + k // self.n_agents for k in range(self.num_envs)]
        return self._seeds

    def _reset_envs(self, envs: list[int]) -> None:
        """Reset the state of the given env copies (per-env RNG draws, like the reference ``reset``)."""
        n_a, size = self.n_agents, self.size
        picks = []
        for i in envs:
            seed, options = self._seeds[i * n_a], self._options[i * n_a]
            rng = self._rngs[i]
            if seed is not None or rng is None:
                rng, _ = seeding.np_random(seed)
                self._rngs[i] = rng
                self._seeds[i * n_a : (i + 1) * n_a] = [None] * n_a
            if options and ("agents" in options or "treasures" in options):
                self.template.reset(options=options)  # validates and places by hand (no RNG draw)
                placed = (*self.template.positions, *self.template.treasures)
                picks.append(self._free_index[[r * size + c for r, c in placed]])
            else:
                picks.append(rng.choice(len(self._free), n_a + self.n_treasures, replace=False))
            self.reset_infos[i * n_a : (i + 1) * n_a] = [{"treasures_collected": 0} for _ in range(n_a)]
        idx = np.asarray(envs, dtype=np.int64)
        cells = self._free[np.stack(picks)]  # free-cell indices -> cells
        self._pos[idx] = cells[:, :n_a]
        self._treasure[idx] = self._tcell[idx] = cells[:, n_a:]
        grid_idx = self._env_off[idx][:, None] + cells[:, n_a:]
        self._tgrid.reshape(self.n_envs, -1)[idx] = False
        self._tgrid[grid_idx] = True
        self._tid[grid_idx] = np.arange(self.n_treasures)
        self._collected[idx] = 0
        self._slot_collected = self._collected[self._slot_env].tolist()
        self._start_tick[idx] = self._tick
        self._next_truncation = int(self._start_tick.min()) + self.max_cycles
        self._slot_return[idx] = 0.0

    def reset(self) -> VecEnvObs:
        """Reset every env (pending seeds/options are used once); returns ``(num_envs, obs_dim)`` float32."""
        self._reset_envs(list(range(self.n_envs)))
        self._reset_options()
        self._obs = self._observations(self._pos, self._tcell, self._tick - self._start_tick)
        return self._obs.reshape(self.num_envs, -1).copy()

    # ------------------------------------------------------------------ step
    def step_wait(self) -> VecEnvStepReturn:
        acts = self._actions
        if acts.view(np.uint64).max() >= self._n_actions:  # negative actions wrap to huge values
            self._check_actions(self._n_actions)
        n, n_a = self.n_envs, self.n_agents
        move = self._move[self._pos, acts.reshape(n, n_a)]  # (n, n_a, 3): next cell, collecting cell, event
        self._pos = move[:, :, 0].copy()
        events = move[:, :, 2].copy()
        rewards = _EVENT_REWARD[events]
        grid_idx = self._env_off[:, None] + move[:, :, 1]
        hits = self._tgrid[grid_idx]
        terminated = self._collect(hits, grid_idx, events, rewards) if np.count_nonzero(hits) else None
        self._tick += 1
        self._slot_return += rewards
        steps = self._tick - self._start_tick
        names = self._event_names[events.reshape(-1)].tolist()
        infos: list[dict[str, Any]] = [
            {"treasures_collected": c, "event": e} for c, e in zip(self._slot_collected, names, strict=True)
        ]
        if self._tick >= self._next_truncation:  # only then can an episode time out
            truncated = steps >= self.max_cycles
            dones = truncated if terminated is None else terminated | truncated
        else:
            dones = self._no_dones if terminated is None else terminated
        if not np.count_nonzero(dones):
            self._obs = self._observations(self._pos, self._tcell, steps)
            return self._result(rewards, dones, infos)
        ended = np.flatnonzero(dones)
        last = (self._pos[ended], self._tcell[ended], steps[ended])  # terminal states
        ended_list = ended.tolist()
        for i in ended_list:
            self._finish_episode(i, infos, terminated is not None and bool(terminated[i]))
        self._reset_envs(ended_list)
        # one observation pass over the new states of all envs + the terminal states of the ended ones
        obs = self._observations(
            np.concatenate([self._pos, last[0]]),
            np.concatenate([self._tcell, last[1]]),
            np.concatenate([self._tick - self._start_tick, last[2]]),
        )
        self._obs = obs[:n]
        for k, i in enumerate(ended_list):
            for j in range(n_a):
                infos[i * n_a + j]["terminal_observation"] = obs[n + k, j]
        return self._result(rewards, dones, infos)

    def _result(
        self, rewards: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]]
    ) -> VecEnvStepReturn:
        obs = self._obs.reshape(self.num_envs, -1).copy()
        return obs, rewards.reshape(-1), dones[self._slot_env], infos

    def _collect(
        self, hits: np.ndarray, grid_idx: np.ndarray, events: np.ndarray, rewards: np.ndarray
    ) -> np.ndarray:
        """Collect the treasures hit this step (the lowest agent index wins a shared cell); ``terminated``."""
        flat = np.flatnonzero(hits)  # env-major, agent-minor: the reference's move order
        cells = grid_idx.reshape(-1)[flat]
        if len(flat) > 1 and len(set(cells.tolist())) < len(flat):  # two agents onto one treasure
            _, first = np.unique(cells, return_index=True)  # first occurrence = lowest agent index
            flat, cells = flat[first], cells[first]
        env = self._slot_env[flat]
        self._tgrid[cells] = False
        self._tcell[env, self._tid[cells]] = self._cells
        events.reshape(-1)[flat] = _TREASURE
        count = np.bincount(env, minlength=self.n_envs)
        self._collected += count
        if self.shared:
            rewards += self._bonus[count][:, None]
        else:
            rewards.reshape(-1)[flat] += self._bonus[1]
        self._slot_collected = self._collected[self._slot_env].tolist()
        return self._collected == self.n_treasures

    def _finish_episode(self, i: int, infos: list[dict[str, Any]], term: bool) -> None:
        """Episode-end infos of env ``i`` (all but ``terminal_observation``) and its monitor row."""
        base = i * self.n_agents
        trunc = not term
        for j in range(self.n_agents):
            info = infos[base + j]
            info["is_success"] = term
            info["TimeLimit.truncated"] = trunc
        team = self._slot_return[i]
        ep = self._episode_info(float(sum(team.tolist())), self._tick - int(self._start_tick[i]))
        infos[base]["episode"] = ep
        treasures = int(self._collected[i])
        infos[base]["treasures"] = treasures
        if self._writer is not None:
            self._writer.write_row({**ep, "treasures": treasures})

    # ------------------------------------------------------------------ observations
    def _observations(self, pos: np.ndarray, tcell: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """Observations of env states ``pos (n, n_agents)``, ``tcell (n, n_treasures)``, ``steps (n,)``.

        :return: shape ``(n, n_agents, obs_dim)`` float32.
        """
        n, n_a, n_t, dim = pos.shape[0], self.n_agents, self.n_treasures, self._dim
        # id, own cell, neighbours (egocentric) / own cell, obstacles (book)
        out = self._self_tab[self._agent_off + pos].view(np.float32).reshape(n, n_a, dim)
        if not self.egocentric:
            out[:, :, 2 : 2 + 2 * n_t] = self._tcoord[tcell].view(np.float32).reshape(n, 1, 2 * n_t)
            return out
        out[:, :, n_a + 2] = self._time_left[steps][:, None]
        pos_c = pos * (self._cells + 1)
        keys = self._row_key[:n] + self._dist_key[pos_c[:, :, None] + tcell[:, None, :]]  # (n, n_a, n_t)
        keys = np.sort(keys.reshape(-1), kind="stable")  # nearest first; ties by treasure index
        near = self._rel3[keys & self._pair_mask].view(np.float32).reshape(n, n_a, 3 * n_t)
        start = n_a + 3
        out[:, :, start : start + 3 * n_t] = near
        if n_a > 1:
            start += 3 * n_t
            others = self._rel2[pos_c[:, :, None] + pos[:, self._others]].view(np.float32)
            out[:, :, start : start + 2 * (n_a - 1)] = others.reshape(n, n_a, 2 * (n_a - 1))
        return out

    # ------------------------------------------------------------------ attributes / rendering
    def _sync(self, env_index: int) -> None:
        env, size = self.template, self.size
        env.positions = [divmod(int(c), size) for c in self._pos[env_index]]
        env.treasures = [divmod(int(c), size) for c in self._treasure[env_index]]
        env.present = [bool(c != self._cells) for c in self._tcell[env_index]]
        env.collected = int(self._collected[env_index])
        env.steps = self._tick - int(self._start_tick[env_index])
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
