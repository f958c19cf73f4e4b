"""Batched SISL pursuit (``pettingzoo.sisl.pursuit_v5``): the parameter-sharing team VecEnv of ``n_envs`` copies,
stepped as numpy arrays.

Equivalent, step by step, to the reference path of ``policies: shared`` (no agent id, local critic):
:func:`sbagents.multiagent.groups.team_vec_envs` over ``n_envs`` copies of
``pettingzoo.sisl.pursuit_v5.parallel_env(**env_kwargs)``. Slot ``k`` is pursuer ``k % N`` of copy ``k // N``. Same
``float32`` observations ``(obs_range, obs_range, 3)`` (walls, pursuer counts, evader counts around the pursuer, axes
``[y, x, channel]`` as pursuit's ``observe``), ``float32`` rewards, dones, infos (``{}`` every step; at an episode end,
``terminal_observation`` and ``TimeLimit.truncated`` in every slot of the copy and the team ``episode = {"r", "l",
"t"}`` in its first slot), auto-reset, seeding (copy ``i`` is reset with ``seed + i``) and the team monitor file.

What pursuit does in one parallel step, and how this module does the same on arrays:

- PettingZoo turns its AEC env into a parallel one: the pursuers move one after the other (sub-steps ``0..N-1``)
  and after each sub-step every pursuer's reward is recomputed and added to its parallel reward. A pursuer's tag
  reward (``tag_reward`` per evader on its four neighbour cells, clipped at the borders) therefore counts its old
  cell in the sub-steps before its own move and its new cell from its move on; pursuers never block each other, so
  all moves are computed at once.
- At the last sub-step: evaders whose open neighbour cells (pursuit's ``need_to_surround``) are all held by
  pursuers are caught and leave, every pursuer on such a cell gets ``catch_reward``, the remaining evaders take a
  random move each (``integers(5)`` in evader order, one call of that many numbers: the same numbers), every
  pursuer gets ``urgency_reward``; rewards are blended with their mean by ``shared_reward`` in pursuit's order of
  float64 operations, so the rewards equal the reference's bit for bit.
- The episode terminates when no evader is left and is truncated after ``max_cycles`` steps; copies end at
  different steps and reset one by one. A start draws pursuit's constraint window (two ``uniform`` calls), then
  places the pursuers and the evaders by pursuit's rejection loop (per-position ``integers`` calls), in Python per
  copy: the same generator calls as the reference, so seeded copies see the same episodes.

Batchable kwargs: every constructor argument of pursuit except ``surround=False``, ``freeze_evaders=True``, custom
``evader_controller``/``pursuer_controller`` and a ``render_mode`` (:func:`unsupported_kwargs`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from gymnasium.utils import seeding
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn

from sbagents.batched.base import BatchedTeamVecEnv, check_batchable, unreproduced_kwargs

#: The ``--env`` name (and the id :func:`sbagents.batched.make_batched_vec_env` takes).
PURSUIT_ID = "pettingzoo.sisl.pursuit_v5"
#: PettingZoo sources (:class:`~sbagents.core.env_names.EnvRef.source`) this batched env reproduces.
PURSUIT_SOURCES: tuple[str, ...] = (PURSUIT_ID, f"{PURSUIT_ID}:parallel_env")
#: What the batched env supports, for error messages.
PURSUIT_SUPPORT = "any pursuit kwargs but surround=False, freeze_evaders=True, custom controllers or a render_mode"

#: kwarg -> whether the batched env reproduces a value of it (the kwargs not listed: any valid value).
_REPRODUCED: dict[str, Callable[[Any], bool]] = {
    "surround": bool,
    "freeze_evaders": lambda v: not v,
    "evader_controller": lambda v: v is None,
    "pursuer_controller": lambda v: v is None,
    "render_mode": lambda v: v is None,
}
#: pursuit's moves (``DiscreteAgent.motion_range``) and catch neighbourhood (``surround_mask``), as ``(dx, dy)``.
_MOVES = np.array([[-1, 0], [1, 0], [0, 1], [0, -1], [0, 0]], dtype=np.int64)
_AROUND = np.array([[-1, 0], [1, 0], [0, 1], [0, -1]], dtype=np.int64)


def unsupported_kwargs(env_kwargs: Mapping[str, Any]) -> list[str]:
    """The env kwargs whose values the batched env does not reproduce, as ``key=value`` (empty: batchable)."""
    return unreproduced_kwargs(env_kwargs, _REPRODUCED)


def need_to_surround(map_matrix: np.ndarray) -> np.ndarray:
    """Pursuit's ``need_to_surround`` for every cell, ``(x_size, y_size)`` int: the neighbour cells that must hold a
    pursuer for an evader there to be caught (four, less borders and walls, with pursuit's own bounds check)."""
    xs, ys = map_matrix.shape
    out = np.zeros((xs, ys), dtype=np.int64)
    for x in range(xs):
        for y in range(ys):
            n = 4 - int(x in (0, xs - 1)) - int(y in (0, ys - 1))
            for dx, dy in _AROUND:
                xn, yn = x + dx, y + dy
                if 0 < xn < xs and 0 < yn < ys and map_matrix[xn, yn] == -1:
                    n -= 1
            out[x, y] = n
    return out


class BatchedPursuitVecEnv(BatchedTeamVecEnv):
    """``n_envs`` pursuit teams as one parameter-sharing SB3 ``VecEnv`` (``n_envs * n_pursuers`` slots).

    :param n_envs: number of env copies (teams).
    :param env_kwargs: keyword arguments of ``pettingzoo.sisl.pursuit_v5.parallel_env`` (see
        :func:`unsupported_kwargs`).
    :param monitor_path: if given, team episodes are written to this SB3 monitor file (``<path>.monitor.csv``).
    :raises ValueError: ``n_envs < 1``, or kwargs the batched env does not reproduce.

    Observations have shape ``(n_envs * N, R, R, 3)`` float32 (``R = obs_range``); actions ``(n_envs * N,)`` in
    ``0..4``.
    """

    def __init__(
        self, n_envs: int, env_kwargs: dict[str, Any] | None = None, monitor_path: str | None = None
    ) -> None:
        from pettingzoo.sisl import pursuit_v5  # optional dependency (the pettingzoo-envs extra)

        kwargs = dict(env_kwargs or {})
        check_batchable(n_envs, unsupported_kwargs(kwargs), PURSUIT_ID, PURSUIT_SUPPORT)
        env = pursuit_v5.parallel_env(**kwargs)  # the template; validates the kwargs as the reference does
        env.reset(seed=0)
        game = env.unwrapped.env  # pursuit's Pursuit object
        self.possible_agents = list(env.possible_agents)
        self.n_pursuers, self.n_evaders = game.n_pursuers, game.n_evaders
        self.max_cycles, self.local_ratio = game.max_cycles, game.local_ratio
        self._tag, self._catch, self._urgency = game.tag_reward, game.catch_reward, game.urgency_reward
        self._window = game.constraint_window
        self._map = np.array(game.map_matrix, dtype=np.int64)
        self._xs, self._ys = self._map.shape
        self._free = self._map != -1
        self._need = need_to_surround(self._map)
        self._range = game.obs_range
        pad = self._pad = game.obs_offset
        # the observation canvas: walls (1 outside the map and on buildings), pursuer and evader counts
        self._canvas = np.zeros((n_envs, 3, self._xs + 2 * pad, self._ys + 2 * pad), dtype=np.float32)
        self._canvas[:, 0] = 1.0
        self._canvas[:, 0, pad:pad + self._xs, pad:pad + self._ys] = np.abs(self._map)
        n, n_p, n_e = n_envs, self.n_pursuers, self.n_evaders
        self._pursuers = np.zeros((n, n_p, 2), dtype=np.int64)
        self._evaders = np.zeros((n, n_e, 2), dtype=np.int64)
        self._alive = np.zeros((n, n_e), dtype=bool)
        self._frames = np.zeros(n, dtype=np.int64)
        self._returns = np.zeros((n, n_p), dtype=np.float64)
        self._rngs: list[np.random.Generator | None] = [None] * n
        self._copy = np.arange(n)[:, None]
        self._order = np.arange(n_p)[None, :]
        super().__init__(n * n_p, n_p, env, env.observation_space(self.possible_agents[0]),
                         env.action_space(self.possible_agents[0]), monitor_path,
                         str(env.metadata.get("name", "team")))  # the reference's monitor header
        self._n_actions = int(self.action_space.n)  # type: ignore[attr-defined]

    # ------------------------------------------------------------------ reset
    def _place(self, rng: np.random.Generator, count: int, bounds: tuple[int, int, int, int]) -> np.ndarray:
        """Pursuit's ``create_agents(randinit=True)``: ``count`` positions, none on or beside an earlier one."""
        xl, xu, yl, yu = bounds
        blocked = np.zeros((self._xs + 2, self._ys + 2), dtype=bool)
        out = np.zeros((count, 2), dtype=np.int64)
        for k in range(count):
            while True:
                x, y = int(rng.integers(xl, xu)), int(rng.integers(yl, yu))
                if self._free[x, y] and not blocked[x + 1, y + 1]:
                    break
            blocked[x + 1, y + 1] = blocked[x + 2, y + 1] = blocked[x, y + 1] = True
            blocked[x + 1, y + 2] = blocked[x + 1, y] = True
            out[k] = x, y
        return out

    def _start(self, i: int) -> None:
        """Draw copy ``i``'s start from its generator (pursuit's ``reset``) and zero its episode."""
        rng = self._rngs[i]
        assert rng is not None
        w = self._window
        x0, y0 = rng.uniform(0.0, 1.0 - w), rng.uniform(0.0, 1.0 - w)
        bounds = (int(self._xs * x0), int(self._xs * (x0 + w)), int(self._ys * y0), int(self._ys * (y0 + w)))
        self._pursuers[i] = self._place(rng, self.n_pursuers, bounds)
        self._evaders[i] = self._place(rng, self.n_evaders, bounds)
        self._alive[i] = True
        self._frames[i] = 0
        self._returns[i] = 0.0

    def reset(self) -> VecEnvObs:
        """Reset every copy (pending seeds are used once); returns ``(num_envs, R, R, 3)`` float32."""
        for i in range(self.n_envs):
            seed = self._seeds[i * self.n_pursuers]
            if seed is not None or self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(seed)
            self._start(i)
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return self._observe()

    # ------------------------------------------------------------------ step
    def _counts(self, positions: np.ndarray, alive: np.ndarray | None = None) -> np.ndarray:
        """Agents per cell ``(n_envs, x_size, y_size)`` int of positions ``(n_envs, m, 2)`` (``alive`` masks)."""
        cells = (self._copy * self._xs + positions[..., 0]) * self._ys + positions[..., 1]
        flat = cells.ravel() if alive is None else cells[alive]
        counts = np.bincount(flat, minlength=self.n_envs * self._xs * self._ys)
        return counts.reshape(self.n_envs, self._xs, self._ys)

    def _observe(self) -> np.ndarray:
        """Every pursuer's window ``(num_envs, R, R, 3)`` float32: pursuit's ``observe`` of the current state."""
        pad, canvas = self._pad, self._canvas
        canvas[:, 1, pad:pad + self._xs, pad:pad + self._ys] = self._counts(self._pursuers)
        canvas[:, 2, pad:pad + self._xs, pad:pad + self._ys] = self._counts(self._evaders, self._alive)
        windows = np.lib.stride_tricks.sliding_window_view(canvas, (self._range, self._range), axis=(2, 3))
        x, y = self._pursuers[..., 0].ravel(), self._pursuers[..., 1].ravel()
        picked = windows[np.repeat(np.arange(self.n_envs), self.n_pursuers), :, x, y]  # (slots, 3, R_x, R_y)
        return np.ascontiguousarray(picked.transpose(0, 3, 2, 1))

    def _moved(self, positions: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """``DiscreteAgent.step``: positions after ``actions``; a move off the map or into a building is refused."""
        target = positions + _MOVES[actions]
        x, y = target[..., 0], target[..., 1]
        inside = (x >= 0) & (x < self._xs) & (y >= 0) & (y < self._ys)
        ok = inside & self._free[np.clip(x, 0, self._xs - 1), np.clip(y, 0, self._ys - 1)]
        return np.where(ok[..., None], target, positions)

    def _tag_rewards(self, evader_counts: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """Pursuit's ``reward()`` before the division: ``tag_reward`` times the evaders on the clipped neighbour
        cells, ``(n_envs, N)`` float64."""
        near = np.zeros(positions.shape[:2], dtype=np.int64)
        for dx, dy in _AROUND:
            x = np.clip(positions[..., 0] + dx, 0, self._xs - 1)
            y = np.clip(positions[..., 1] + dy, 0, self._ys - 1)
            near += evader_counts[self._copy, x, y]
        return self._tag * near  # type: ignore[no-any-return]

    def _catches(self) -> np.ndarray:
        """Remove the surrounded evaders; returns which pursuers took part, ``(n_envs, N)`` bool."""
        held = np.zeros((self.n_envs, self._xs + 2, self._ys + 2), dtype=bool)  # pursuer cells, 1-cell margin
        held[self._copy, self._pursuers[..., 0] + 1, self._pursuers[..., 1] + 1] = True
        ex, ey = self._evaders[..., 0], self._evaders[..., 1]
        around = sum(held[self._copy, ex + 1 + dx, ey + 1 + dy].astype(np.int64) for dx, dy in _AROUND)
        caught = self._alive & (around == self._need[ex, ey])
        credit = np.zeros_like(held)  # the catching cells of the caught evaders
        ci, ki = np.nonzero(caught)
        for dx, dy in _AROUND:
            credit[ci, ex[ci, ki] + 1 + dx, ey[ci, ki] + 1 + dy] = True
        self._alive &= ~caught
        return credit[self._copy, self._pursuers[..., 0] + 1, self._pursuers[..., 1] + 1]  # type: ignore[no-any-return]

    def _move_evaders(self) -> None:
        """Every evader left takes pursuit's random move, drawn from its copy's generator in evader order."""
        counts = self._alive.sum(axis=1)
        draws = [rng.integers(5, size=int(c)) for rng, c in zip(self._rngs, counts, strict=True)  # type: ignore[union-attr]
                 if c]
        if not draws:
            return
        actions = np.full(self._alive.shape, 4, dtype=np.int64)
        actions[self._alive] = np.concatenate(draws)
        self._evaders = self._moved(self._evaders, actions)

    def _rewards(self, tag_old: np.ndarray, tag_new: np.ndarray, caught_by: np.ndarray) -> np.ndarray:
        """The parallel step's rewards ``(n_envs, N)`` float64: the sum over sub-steps of pursuit's rewards."""
        n_p, lr = self.n_pursuers, self.local_ratio
        total = np.zeros((self.n_envs, n_p))
        for k in range(n_p):
            local = np.where(self._order <= k, tag_new, tag_old) / n_p
            if k == n_p - 1:
                local = local + self._catch * caught_by
                local = local + self._urgency
            total = total + (lr * local + (1 - lr) * local.mean(axis=1, keepdims=True))
        return total

    def step_wait(self) -> VecEnvStepReturn:
        acts = self._checked_actions(self._rngs[0] is not None, self._n_actions)
        evader_counts = self._counts(self._evaders, self._alive)
        tag_old = self._tag_rewards(evader_counts, self._pursuers)
        self._pursuers = self._moved(self._pursuers, acts.reshape(self.n_envs, self.n_pursuers))
        tag_new = self._tag_rewards(evader_counts, self._pursuers)
        caught_by = self._catches()
        self._move_evaders()
        rewards64 = self._rewards(tag_old, tag_new, caught_by)
        self._returns += rewards64
        self._frames += 1
        truncated = self._frames >= self.max_cycles
        ended = truncated | ~self._alive.any(axis=1)
        obs = self._observe()
        rewards = rewards64.astype(np.float32).reshape(self.num_envs)
        dones = np.repeat(ended, self.n_pursuers)
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        if ended.any():
            obs = self._finish_episodes(obs, np.flatnonzero(ended), truncated, infos)
        return obs, rewards, dones, infos

    def _finish_episodes(self, obs: np.ndarray, ended: np.ndarray, truncated: np.ndarray,
                         infos: list[dict[str, Any]]) -> np.ndarray:
        """Episode-end infos and monitor rows of the copies that ended, which then restart; returns the
        observations with their first ones."""
        n_p = self.n_pursuers
        seconds = self._monitor_seconds()
        for i in ended.tolist():
            for j in range(n_p):
                infos[i * n_p + j] = {"terminal_observation": obs[i * n_p + j].copy(),
                                      "TimeLimit.truncated": bool(truncated[i])}
            team = 0.0
            for r in self._returns[i].tolist():  # the reference: sum(per-agent returns) in agent order
                team += r
            ep = {"r": round(team, 6), "l": int(self._frames[i]), "t": seconds}
            infos[i * n_p]["episode"] = ep
            if self._writer is not None:
                self._writer.write_row(ep)
            self._start(i)
        return self._observe()

    # ------------------------------------------------------------------ attributes
    def _sync(self, env_index: int) -> None:
        """Copy env ``env_index``'s positions, evaders left and step count into the template's pursuit game."""
        from pettingzoo.sisl.pursuit.utils import agent_utils
        from pettingzoo.sisl.pursuit.utils.agent_layer import AgentLayer

        i, game = env_index, self.template.unwrapped.env
        for j, pursuer in enumerate(game.pursuers):
            pursuer.set_position(*self._pursuers[i, j])
        left = self._evaders[i][self._alive[i]]
        game.evaders = agent_utils.create_agents(len(left), game.map_matrix, game.obs_range, game.np_random)
        for evader, (x, y) in zip(game.evaders, left, strict=True):
            evader.set_position(x, y)
        game.evader_layer = AgentLayer(self._xs, self._ys, game.evaders)
        game.evaders_gone[:] = ~self._alive[i]
        game.model_state[1] = game.pursuer_layer.get_state_matrix()
        game.model_state[2] = game.evader_layer.get_state_matrix()
        game.frames = int(self._frames[i])
