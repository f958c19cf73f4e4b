"""Batched GridWorld: ``n_envs`` copies of :class:`~sbagents.envs.gridworld.GridWorldEnv` stepped as arrays.

Equivalent, step by step, to ``make_vec_env("sbagents/GridWorld-v0", n_envs, ...)`` (a ``DummyVecEnv`` of
``Monitor``-wrapped envs): same observations (``int64`` cell indices, shape ``(n_envs,)``), ``float32``
rewards, dones, and infos (``event`` and ``TimeLimit.truncated`` every step; at episode end
``is_success``, ``terminal_observation`` and Monitor's ``episode = {"r", "l", "t"}``), auto-reset, and one
monitor file ``<monitor_dir>/<i>.monitor.csv`` per env copy. GridWorld has no randomness, so seeds
(accepted for API compatibility) do not change trajectories.

A step is one call of the compiled kernel :func:`sbagents.batched.kernels.gridworld_step` over
precomputed ``(cell, action)`` tables: next cell, reward, goal reached and event.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.monitor import Monitor, ResultsWriter
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn

from sbagents.batched.base import BatchedVecEnv, monitor_writer
from sbagents.batched.kernels import gridworld_step
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
        # rows: current cell * 4 (table row), episode length, length of the episode that just ended
        self._counters = np.zeros((3, n_envs), dtype=np.int64)
        self._start_key = self._start * 4
        self._counters[0] = self._start_key
        self._returns = np.zeros((2, n_envs), dtype=np.float64)  # rows: episode return, return of an ended one
        self._terminated = np.zeros(n_envs, dtype=bool)  # kernel output: the episode reached the goal
        super().__init__(n_envs, 1, template, template.observation_space, template.action_space)
        self._writers: list[ResultsWriter | None] = [
            monitor_writer(monitor_dir, i, env_id, self._t_start) for i in range(n_envs)
        ]
        self._monitored = monitor_dir is not None

    def _build_tables(self, env: GridWorldEnv) -> None:
        """Flat ``(cell * 4 + action)`` tables: next cell, event code, goal reached (packed) and reward (float32)."""
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
        goal = nxt.reshape(-1) == int(env.to_obs(env.goal))
        # rows of ``cell * 4 + action``: next cell's table row (next cell * 4), event code, reaches the goal
        self._table = np.stack([nxt.reshape(-1) * 4, event.reshape(-1), goal.astype(np.int64)], axis=1)
        self._reward = rew.reshape(-1)

    # ------------------------------------------------------------------ core API
    def reset(self) -> VecEnvObs:
        """Reset every copy to the start cell; returns the observations, shape ``(n_envs,)`` int64."""
        self._counters[0], self._counters[1] = self._start_key, 0
        self._returns[0] = 0.0
        self.reset_infos = [{} for _ in range(self.num_envs)]
        self._reset_seeds()
        self._reset_options()
        return np.full(self.num_envs, self._start, dtype=np.int64)

    def step_wait(self) -> VecEnvStepReturn:
        acts, n = self._actions, self.num_envs
        obs = np.empty(n, dtype=np.int64)
        rewards = np.empty(n, dtype=np.float32)
        dones = np.empty(n, dtype=bool)
        events = np.empty(n, dtype=np.int64)
        terminated = self._terminated  # read only in this step
        n_done = gridworld_step(acts, self._counters, self._returns, self._table, self._reward, self._start_key,
                                self.max_steps, obs, rewards, dones, terminated, events)
        if n_done < 0:
            self._raise_invalid_action(-1 - n_done, 4)
        names = EVENTS
        infos: list[dict[str, Any]] = [{"event": names[e], "TimeLimit.truncated": False} for e in events.tolist()]
        if n_done:
            ended = np.flatnonzero(dones).tolist()
            self._finish_episodes(ended, infos, obs, terminated)
            obs[dones] = self._start
        return obs, rewards, dones, infos

    def _finish_episodes(
        self, ended: list[int], infos: list[dict[str, Any]], obs: np.ndarray, terminated: np.ndarray
    ) -> None:
        """Episode-end infos (``is_success``, ``TimeLimit.truncated``, ``episode``, ``terminal_observation``)."""
        returns, lengths = self._returns[1].tolist(), self._counters[2].tolist()
        success, reset_infos = terminated.tolist(), self.reset_infos
        seconds = self._monitor_seconds()
        for i in ended:
            info, term, ret = infos[i], success[i], returns[i]
            ep = {"r": ret if ret.is_integer() else round(ret, 6), "l": lengths[i], "t": seconds}  # Monitor's
            info["is_success"] = term
            info["TimeLimit.truncated"] = not term
            info["episode"] = ep
            info["terminal_observation"] = obs[i]  # a new np.int64 scalar, as the reference
            reset_infos[i] = {}
        if self._monitored:
            for i in ended:
                self._writers[i].write_row(infos[i]["episode"])  # type: ignore[union-attr]

    def close(self) -> None:
        self._monitored = False
        for k, writer in enumerate(self._writers):
            if writer is not None:
                writer.close()
                self._writers[k] = None

    # ------------------------------------------------------------------ attributes / rendering
    def _sync(self, env_index: int) -> None:
        self.template.agent = self.template.to_cell(int(self._counters[0, env_index]) // 4)
        self.template.steps = int(self._counters[1, env_index])

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        """True for SB3's ``Monitor`` (and its bases), like the reference ``make_vec_env`` envs."""
        wrapped = isinstance(wrapper_class, type) and issubclass(Monitor, wrapper_class)
        return [wrapped for _ in self._env_indices(indices)]
