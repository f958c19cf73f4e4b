"""Batched GridWorld: ``n_envs`` copies of :class:`~sbagents.envs.gridworld.GridWorldEnv` stepped as arrays.

Equivalent, step by step, to ``make_vec_env("sbagents/GridWorld-v0", n_envs, ...)`` (a ``DummyVecEnv`` of
``Monitor``-wrapped envs): same observations (``int64`` cell indices, shape ``(n_envs,)``), ``float32``
rewards, dones, and infos (``event`` and ``TimeLimit.truncated`` every step; at episode end
``is_success``, ``terminal_observation`` and Monitor's ``episode = {"r", "l", "t"}``), auto-reset, and one
monitor file ``<monitor_dir>/<i>.monitor.csv`` per env copy. GridWorld has no randomness, so seeds
(accepted for API compatibility) do not change trajectories.

A step is a lookup in precomputed ``(cell, action)`` tables: next cell, reward and event.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.monitor import Monitor, ResultsWriter
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn

from sbagents.batched.base import BatchedVecEnv, monitor_writer
from sbagents.envs.gridworld import (
    ACTION_DELTAS,
    GOAL_REWARD,
    OBSTACLE_REWARD,
    STEP_REWARD,
    WALL_REWARD,
    GridWorldEnv,
)

GRIDWORLD_ID = "sbagents/GridWorld-v0"
#: Event codes of the transition table -> the reference env's ``info["event"]`` strings.
EVENTS: tuple[str, ...] = ("move", "wall", "obstacle")


class BatchedGridWorldVecEnv(BatchedVecEnv):
    """``n_envs`` GridWorld copies as one SB3 ``VecEnv``, stepped with array operations.

    :param n_envs: number of env copies (= ``num_envs``).
    :param env_kwargs: keyword arguments of :class:`GridWorldEnv` (``size``, ``start``, ``goal``,
        ``obstacles``, ``max_steps``, ``render_mode``).
    :param monitor_dir: if given, SB3 monitor CSVs ``<monitor_dir>/<i>.monitor.csv`` (one per env).
    :param env_id: env id written in the monitor files' header.
    """

    def __init__(
        self,
        n_envs: int,
        env_kwargs: dict[str, Any] | None = None,
        monitor_dir: str | None = None,
        env_id: str = GRIDWORLD_ID,
    ) -> None:
        if n_envs < 1:
            raise ValueError(f"n_envs must be >= 1, got {n_envs}")
        template = GridWorldEnv(**(env_kwargs or {}))
        self.max_steps = template.max_steps
        self._start = int(template.to_obs(template.start))
        self._build_tables(template)
        self._state = np.full(n_envs, self._start, dtype=np.int64)
        self._key = self._state * 4  # current cell's row in the flat tables
        self._tick = 0  # steps since creation; an episode's length is tick - start tick
        self._start_tick = np.zeros(n_envs, dtype=np.int64)
        self._next_truncation = self.max_steps  # earliest tick at which some episode is truncated
        self._ep_return = np.zeros(n_envs, dtype=np.float64)
        super().__init__(n_envs, 1, template, template.observation_space, template.action_space)
        self._writers: list[ResultsWriter | None] = [
            monitor_writer(monitor_dir, i, env_id, self._t_start) for i in range(n_envs)
        ]

    def _build_tables(self, env: GridWorldEnv) -> None:
        """Flat ``(cell * 4 + action)`` tables: next cell, reward (float32), event name, goal reached."""
        n_cells = env.n_rows * env.n_cols
        nxt = np.zeros((n_cells, 4), dtype=np.int64)
        rew = np.zeros((n_cells, 4), dtype=np.float32)
        event = np.zeros((n_cells, 4), dtype=np.int64)
        for cell in range(n_cells):
            row, col = env.to_cell(cell)
            for a, (d_row, d_col) in enumerate(ACTION_DELTAS):
                r2, c2 = row + d_row, col + d_col
                nxt[cell, a] = cell
                if not (0 <= r2 < env.n_rows and 0 <= c2 < env.n_cols):
                    rew[cell, a], event[cell, a] = WALL_REWARD, 1
                elif (r2, c2) in env.obstacles:
                    rew[cell, a], event[cell, a] = OBSTACLE_REWARD, 2
                else:
                    nxt[cell, a] = int(env.to_obs((r2, c2)))
                    rew[cell, a] = GOAL_REWARD if (r2, c2) == env.goal else STEP_REWARD
        self._next = nxt.reshape(-1)  # next cell (the observation)
        self._next_key = self._next * 4  # next cell's row in the flat tables
        self._reward = rew.reshape(-1)
        self._event_name = np.array(EVENTS, dtype=object)[event.reshape(-1)]
        self._reaches_goal = self._next == int(env.to_obs(env.goal))

    # ------------------------------------------------------------------ core API
    def reset(self) -> VecEnvObs:
        """Reset every copy to the start cell; returns the observations, shape ``(n_envs,)`` int64."""
        self._state = np.full(self.num_envs, self._start, dtype=np.int64)
        self._key = self._state * 4
        self._start_tick[:] = self._tick
        self._next_truncation = self._tick + self.max_steps
        self._ep_return[:] = 0.0
        self.reset_infos = [{} for _ in range(self.num_envs)]
        self._reset_seeds()
        self._reset_options()
        return self._state.copy()

    def step_wait(self) -> VecEnvStepReturn:
        acts = self._actions
        if acts.view(np.uint64).max() >= 4:  # negative actions wrap to huge values
            self._check_actions(4)
        key = self._key + acts
        state = self._next[key]
        rewards = self._reward[key]
        terminated = self._reaches_goal[key]
        self._key = self._next_key[key]
        self._tick += 1
        self._ep_return += rewards
        infos: list[dict[str, Any]] = [
            {"event": e, "TimeLimit.truncated": False} for e in self._event_name[key].tolist()
        ]
        n_done = np.count_nonzero(terminated)
        if self._tick >= self._next_truncation:  # only then can an episode time out
            truncated = self._start_tick <= self._tick - self.max_steps
            n_done += np.count_nonzero(truncated)
            dones = terminated | truncated
        else:
            dones = terminated
        if n_done:
            for i in np.flatnonzero(dones).tolist():
                self._finish_episode(i, infos[i], state, bool(terminated[i]))
            state[dones] = self._start
            self._key[dones] = self._start * 4
            self._start_tick[dones] = self._tick
            self._ep_return[dones] = 0.0
            self._next_truncation = int(self._start_tick.min()) + self.max_steps
        self._state = state
        return state.copy(), rewards, dones, infos

    def _finish_episode(self, i: int, info: dict[str, Any], state: np.ndarray, term: bool) -> None:
        info["is_success"] = term
        info["TimeLimit.truncated"] = not term
        ep = self._episode_info(float(self._ep_return[i]), self._tick - int(self._start_tick[i]))
        writer = self._writers[i]
        if writer is not None:
            writer.write_row(ep)
        info["episode"] = ep
        info["terminal_observation"] = state[i]  # np.int64 scalar (a copy), as the reference
        self.reset_infos[i] = {}

    def close(self) -> None:
        for k, writer in enumerate(self._writers):
            if writer is not None:
                writer.close()
                self._writers[k] = None

    # ------------------------------------------------------------------ attributes / rendering
    def _sync(self, env_index: int) -> None:
        self.template.agent = self.template.to_cell(int(self._state[env_index]))
        self.template.steps = self._tick - int(self._start_tick[env_index])

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        """True for SB3's ``Monitor`` (and its bases), like the reference ``make_vec_env`` envs."""
        wrapped = isinstance(wrapper_class, type) and issubclass(Monitor, wrapper_class)
        return [wrapped for _ in self._env_indices(indices)]
