"""Compiled (numba) step kernels of the batched VecEnvs.

Each kernel advances every env copy in one call: a compiled loop over envs (and agents), so a step costs
one dispatch instead of one numpy operation per quantity. State lives in numpy arrays owned by the
VecEnv; the kernels update it in place and write the step's outputs into fresh arrays passed in.
The compiled code is cached in the per-user cache folder (:func:`sbagents.cache.cache_dir`, or numba's own
``NUMBA_CACHE_DIR`` when set), never next to this file, so only the first import on a machine pays the
compile time (a few seconds).

Conventions: cells are flat indices ``row * size + col``; a collected treasure's cell is the sentinel
``n_cells``. Observation values are the float32 of the float64 values the reference envs compute in
Python (precomputed where they are tables).

Kernels call helpers once per step, never once per env: each numba call pays reference counting on its
array arguments (measured ~75 ns per call here), which per team cost more than the observations themselves.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
from numba import njit
from numba.core import config as numba_config

from sbagents.cache import cache_dir


@contextlib.contextmanager
def _cache_in_user_folder() -> Iterator[None]:
    """Point numba's cache at ``<cache dir>/numba`` while kernels are decorated (numba picks the cache folder
    at decoration time), unless the user set ``NUMBA_CACHE_DIR``; numba's setting is restored afterwards."""
    config: Any = numba_config  # numba sets its options as module attributes at import (untyped)
    if config.CACHE_DIR:
        yield
        return
    config.CACHE_DIR = str(cache_dir("numba"))
    try:
        yield
    finally:
        config.CACHE_DIR = ""


def kernel(**options: Any) -> Callable[[Callable[..., Any]], Any]:
    """``numba.njit(cache=True, **options)`` with the cache in the user's cache folder."""

    def decorate(fn: Callable[..., Any]) -> Any:
        with _cache_in_user_folder():
            return njit(cache=True, **options)(fn)

    return decorate


@kernel()
def first_invalid_action(acts: np.ndarray, n_actions: int) -> int:
    """Index of the first action outside ``0..n_actions-1``, or -1 if all are valid."""
    for i in range(acts.shape[0]):
        if acts[i] < 0 or acts[i] >= n_actions:
            return i
    return -1


# ---------------------------------------------------------------------------------------------- GridWorld
@kernel()
def gridworld_step(
    acts: np.ndarray,
    counters: np.ndarray,
    returns: np.ndarray,
    table: np.ndarray,
    reward: np.ndarray,
    start_key: int,
    max_steps: int,
    obs: np.ndarray,
    rew: np.ndarray,
    done: np.ndarray,
    term: np.ndarray,
    ev: np.ndarray,
) -> int:
    """One GridWorld step of every copy; returns the number of finished episodes, or ``-1 - i`` (nothing
    changed) if env ``i``'s action is not in ``0..3``.

    State (updated): ``counters (3, n)`` int64 rows: current cell * 4, episode length, and (output) the
    length of an episode that ended; ``returns (2, n)`` float64 rows: episode return, and (output) the
    return of an episode that ended. Tables indexed by ``cell * 4 + action``: ``table (cells * 4, 3)``
    next cell * 4, event code, move reaches the goal; ``reward`` float32. Outputs ``(n,)``: ``obs`` the
    cell after the move (a finished episode's terminal observation: the caller resets it), ``rew``,
    ``done``, ``term`` (goal reached), ``ev``. A finished copy is reset in place to
    ``start_key`` with zero length and return.
    """
    bad = first_invalid_action(acts, 4)
    if bad >= 0:
        return -1 - bad
    n_done = 0
    for i in range(acts.shape[0]):
        k = counters[0, i] + acts[i]
        nk = table[k, 0]
        r = reward[k]
        rew[i] = r
        ev[i] = table[k, 1]
        obs[i] = nk >> 2
        length = counters[1, i] + 1
        ret = returns[0, i] + r
        t = table[k, 2] != 0
        term[i] = t
        if t or length >= max_steps:
            done[i] = True
            counters[2, i] = length
            returns[1, i] = ret
            counters[0, i] = start_key
            counters[1, i] = 0
            returns[0, i] = 0.0
            n_done += 1
        else:
            done[i] = False
            counters[0, i] = nk
            counters[1, i] = length
            returns[0, i] = ret
    return n_done


# ------------------------------------------------------------------------------------------ TreasureHunt
# Packed state of ``n`` teams: ``cells (n, n_agents + 2 * n_treasures)`` int64 = agent cells | treasure cells
# (the sentinel ``n_cells`` once collected) | initial treasure cells; ``counters (n, 2)`` int64 = treasures
# collected, episode length; ``returns (n,)`` float64 team return. ``params`` int64 = (shared reward,
# max_cycles, egocentric observation).
@kernel()
def _write_obs(
    teams: np.ndarray,
    n_teams: int,
    cells: np.ndarray,
    counters: np.ndarray,
    params: np.ndarray,
    coords: np.ndarray,
    neighbours: np.ndarray,
    book_tail: np.ndarray,
    offs: np.ndarray,
    out: np.ndarray,
) -> None:
    """Write the observations of the teams ``teams[:n_teams]`` into ``out (n, n_agents, dim)`` (rows zeroed).

    One call covers many teams: a numba call per team would pay reference counting on every array argument.
    ``coords (n_cells + 1, 2)`` row/col of each cell (the sentinel: -1, -1); ``neighbours (n_cells, 4)``
    blocked up/down/left/right flags; ``book_tail`` the book layout's obstacle coordinates; ``offs`` the
    float32 value of ``d / (grid_size - 1)`` at index ``d + grid_size - 1``.
    """
    n_a, dim = out.shape[1], out.shape[2]
    n_t = (cells.shape[1] - n_a) // 2
    n_cells = coords.shape[0] - 1
    zero = (offs.shape[0] - 1) // 2  # index of an offset of 0
    keys = np.empty(n_t, dtype=np.int64)
    trow = np.empty(n_t, dtype=np.int64)
    tcol = np.empty(n_t, dtype=np.int64)
    for q in range(n_teams):
        i = teams[q]
        if params[2] == 0:  # book layout
            for j in range(n_a):
                out[i, j, 0] = coords[cells[i, j], 0]
                out[i, j, 1] = coords[cells[i, j], 1]
                for k in range(n_t):
                    out[i, j, 2 + 2 * k] = coords[cells[i, n_a + k], 0]
                    out[i, j, 3 + 2 * k] = coords[cells[i, n_a + k], 1]
                for d in range(book_tail.shape[0]):
                    out[i, j, 2 + 2 * n_t + d] = book_tail[d]
            continue
        time_left = 1.0 - counters[i, 1] / params[1]
        m = 0  # the team's present treasures, in index order
        for k in range(n_t):
            t = cells[i, n_a + k]
            if t != n_cells:
                trow[m] = coords[t, 0]
                tcol[m] = coords[t, 1]
                m += 1
        for j in range(n_a):
            cell = cells[i, j]
            row, col = coords[cell, 0], coords[cell, 1]
            out[i, j, j] = 1.0
            out[i, j, n_a] = offs[zero + row]
            out[i, j, n_a + 1] = offs[zero + col]
            out[i, j, n_a + 2] = time_left
            # rank the present treasures by (Manhattan distance, index): a branch-free stable sort; the
            # slots of collected ones keep the zero padding
            for k in range(m):
                keys[k] = (abs(trow[k] - row) + abs(tcol[k] - col)) * n_t + k
            for k in range(m):
                rank = 0
                for k2 in range(m):
                    rank += keys[k2] < keys[k]
                b = n_a + 3 + 3 * rank
                out[i, j, b] = 1.0
                out[i, j, b + 1] = offs[zero + trow[k] - row]
                out[i, j, b + 2] = offs[zero + tcol[k] - col]
            b = n_a + 3 + 3 * n_t
            for j2 in range(n_a):
                if j2 != j:
                    other = cells[i, j2]
                    out[i, j, b] = offs[zero + coords[other, 0] - row]
                    out[i, j, b + 1] = offs[zero + coords[other, 1] - col]
                    b += 2
            for d in range(4):
                out[i, j, dim - 4 + d] = neighbours[cell, d]


@kernel(inline="always")
def _place_team(i: int, picks: np.ndarray, free: np.ndarray, cells: np.ndarray, n_a: int, n_t: int) -> None:
    """Team ``i``'s agents, then treasures, on the free cells ``free[picks]`` (``picks (n_a + n_t,)``)."""
    for j in range(n_a):
        cells[i, j] = free[picks[j]]
    for k in range(n_t):
        cells[i, n_a + k] = cells[i, n_a + n_t + k] = free[picks[n_a + k]]


@kernel()
def treasure_step(
    acts: np.ndarray,
    cells: np.ndarray,
    counters: np.ndarray,
    returns: np.ndarray,
    move: np.ndarray,
    reward_of: np.ndarray,
    params: np.ndarray,
    coords: np.ndarray,
    neighbours: np.ndarray,
    book_tail: np.ndarray,
    offs: np.ndarray,
    free: np.ndarray,
    next_picks: np.ndarray,
    obs: np.ndarray,
    rew: np.ndarray,
    flags: np.ndarray,
    slot_info: np.ndarray,
    finals: np.ndarray,
    final_returns: np.ndarray,
    terminal: np.ndarray,
) -> int:
    """One step of every team (agents move in index order); returns the number of finished episodes, or
    ``-1 - s`` (nothing changed) if slot ``s``'s action is out of range.

    ``move (n_cells, n_actions, 2)``: next cell and event code (0 move, 1 wall, 2 obstacle; 3 treasure is set
    here); ``reward_of (5,)``: rewards of the four events, then the per-treasure bonus. Outputs: ``obs (n,
    n_agents, dim)`` float32 (zeroed by the caller), ``rew (n * n_agents,)``, ``flags (2, n)`` done and
    terminated, ``slot_info (2, n * n_agents)`` event code and treasures collected (after the step).
    A finished team's episode is reported in the first ``n_done`` columns of ``finals (4, n)`` (team index,
    length, treasures, terminated), ``final_returns`` and rows of ``terminal (n, n_agents, dim)`` (its last
    observations); the team is then reset in place onto its pre-drawn ``next_picks[i]`` (indices into
    ``free``), whose observations replace the terminal ones in ``obs``. The caller draws the next picks.
    """
    bad = first_invalid_action(acts, move.shape[1])
    if bad >= 0:
        return -1 - bad
    n, n_a = cells.shape[0], acts.shape[0] // cells.shape[0]
    n_t = (cells.shape[1] - n_a) // 2
    n_cells = coords.shape[0] - 1
    shared = params[0] != 0
    n_done = 0
    for i in range(n):
        total = 0
        for j in range(n_a):
            s = i * n_a + j
            cell = cells[i, j]
            nxt = move[cell, acts[s], 0]
            e = move[cell, acts[s], 1]
            found = 0
            if e == 0:
                cells[i, j] = nxt
                for k in range(n_t):
                    if cells[i, n_a + k] == nxt:
                        cells[i, n_a + k] = n_cells
                        found += 1
                        e = 3
            slot_info[0, s] = e
            rew[s] = reward_of[e] if shared else reward_of[e] + reward_of[4] * found
            total += found
        counters[i, 0] += total
        collected = counters[i, 0]
        team = 0.0
        for j in range(n_a):
            s = i * n_a + j
            if shared:
                rew[s] += reward_of[4] * total
            team += rew[s]
            slot_info[1, s] = collected
        returns[i] += team
        counters[i, 1] += 1
        length = counters[i, 1]
        t = collected == n_t
        flags[1, i] = t
        flags[0, i] = t or length >= params[1]
        if flags[0, i]:
            finals[0, n_done] = i
            finals[1, n_done] = length
            finals[2, n_done] = collected
            finals[3, n_done] = t
            final_returns[n_done] = returns[i]
            n_done += 1
    _write_obs(np.arange(n), n, cells, counters, params, coords, neighbours, book_tail, offs, obs)
    if n_done == 0:
        return 0
    ended = finals[0, :n_done]
    for q in range(n_done):  # terminal observations, then the reset onto the pre-drawn starts
        i = ended[q]
        terminal[q] = obs[i]
        _place_team(i, next_picks[i], free, cells, n_a, n_t)
        counters[i, 0] = counters[i, 1] = 0
        returns[i] = 0.0
        obs[i] = 0.0
    _write_obs(ended, n_done, cells, counters, params, coords, neighbours, book_tail, offs, obs)
    return n_done


@kernel()
def treasure_reset(
    picks: np.ndarray,
    free: np.ndarray,
    cells: np.ndarray,
    counters: np.ndarray,
    returns: np.ndarray,
    params: np.ndarray,
    coords: np.ndarray,
    neighbours: np.ndarray,
    book_tail: np.ndarray,
    offs: np.ndarray,
    obs: np.ndarray,
) -> None:
    """Reset every team ``i`` onto the free cells ``free[picks[i]]`` and write all observations (``obs``
    zeroed)."""
    n, n_a = cells.shape[0], obs.shape[1]
    n_t = picks.shape[1] - n_a
    for i in range(n):
        _place_team(i, picks[i], free, cells, n_a, n_t)
        counters[i, 0] = counters[i, 1] = 0
        returns[i] = 0.0
    _write_obs(np.arange(n), n, cells, counters, params, coords, neighbours, book_tail, offs, obs)
