"""Compiled (numba) step kernels of the batched VecEnvs.

Each kernel advances every env copy in one call: a compiled loop over envs (and agents), so a step costs
one dispatch instead of one numpy operation per quantity. State lives in numpy arrays owned by the
VecEnv; the kernels update it in place and write the step's outputs into fresh arrays passed in.
``cache=True`` keeps the compiled code next to this file, so only the first import on a machine pays
the compile time (a few seconds).

Conventions: cells are flat indices ``row * size + col``; a collected treasure's cell is the sentinel
``n_cells``. Arithmetic on observations is done in float64 and stored as float32, exactly as the
reference envs compute it in Python.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def first_invalid_action(acts: np.ndarray, n_actions: int) -> int:
    """Index of the first action outside ``0..n_actions-1``, or -1 if all are valid."""
    for i in range(acts.shape[0]):
        if acts[i] < 0 or acts[i] >= n_actions:
            return i
    return -1


# ---------------------------------------------------------------------------------------------- GridWorld
@njit(cache=True)
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
    flags: np.ndarray,
    ev: np.ndarray,
) -> int:
    """One GridWorld step of every copy; returns the number of finished episodes, or ``-1 - i`` (nothing
    changed) if env ``i``'s action is not in ``0..3``.

    State (updated): ``counters (3, n)`` int64 rows: current cell * 4, episode length, and (output) the
    length of an episode that ended; ``returns (2, n)`` float64 rows: episode return, and (output) the
    return of an episode that ended. Tables indexed by ``cell * 4 + action``: ``table (cells * 4, 3)``
    next cell * 4, event code, move reaches the goal; ``reward`` float32. Outputs ``(n,)``: ``obs`` the
    cell after the move (a finished episode's terminal observation: the caller resets it), ``rew``,
    ``flags (2, n)`` rows done and terminated (goal reached), ``ev``. A finished copy is reset in place to
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
        flags[1, i] = t
        if t or length >= max_steps:
            flags[0, i] = True
            counters[2, i] = length
            returns[1, i] = ret
            counters[0, i] = start_key
            counters[1, i] = 0
            returns[0, i] = 0.0
            n_done += 1
        else:
            flags[0, i] = False
            counters[0, i] = nk
            counters[1, i] = length
            returns[0, i] = ret
    return n_done


# ------------------------------------------------------------------------------------------ TreasureHunt
@njit(cache=True, inline="always")  # inlined: a call per team would pay array refcounting
def _treasure_obs(
    i: int,
    pos: np.ndarray,
    tcell: np.ndarray,
    ep_len: np.ndarray,
    coords: np.ndarray,
    neighbours: np.ndarray,
    book_tail: np.ndarray,
    scale: float,
    egocentric: bool,
    max_cycles: int,
    out: np.ndarray,
    keys: np.ndarray,
) -> None:
    """Write the observations of env ``i``'s agents into ``out[i]`` (shape ``(n_agents, dim)``, zeroed).

    ``coords (n_cells + 1, 2)`` row/col of each cell (the sentinel: -1, -1); ``neighbours (n_cells, 4)``
    blocked up/down/left/right flags; ``book_tail`` the book layout's obstacle coordinates; ``scale`` =
    1 / (grid_size - 1); ``keys (n_treasures,)`` scratch. Only small tables are read (they stay in L1).
    """
    n_a, n_t, dim = pos.shape[1], tcell.shape[1], out.shape[2]
    n_cells = coords.shape[0] - 1
    if not egocentric:
        for j in range(n_a):
            out[i, j, 0] = coords[pos[i, j], 0]
            out[i, j, 1] = coords[pos[i, j], 1]
            for k in range(n_t):
                out[i, j, 2 + 2 * k] = coords[tcell[i, k], 0]
                out[i, j, 3 + 2 * k] = coords[tcell[i, k], 1]
            for d in range(book_tail.shape[0]):
                out[i, j, 2 + 2 * n_t + d] = book_tail[d]
        return
    time_left = 1.0 - ep_len[i] / max_cycles
    for j in range(n_a):
        cell = pos[i, j]
        row, col = coords[cell, 0], coords[cell, 1]
        out[i, j, j] = 1.0
        out[i, j, n_a] = row * scale
        out[i, j, n_a + 1] = col * scale
        out[i, j, n_a + 2] = time_left
        # rank present treasures by (Manhattan distance, index): a branch-free stable sort; collected ones
        # rank last and leave the zero padding
        for k in range(n_t):
            t = tcell[i, k]
            far = 4 * n_cells if t == n_cells else abs(coords[t, 0] - row) + abs(coords[t, 1] - col)
            keys[k] = far * n_t + k
        for k in range(n_t):
            t = tcell[i, k]
            if t == n_cells:
                continue
            rank = 0
            for k2 in range(n_t):
                rank += keys[k2] < keys[k]
            q = n_a + 3 + 3 * rank
            out[i, j, q] = 1.0
            out[i, j, q + 1] = (coords[t, 0] - row) * scale
            out[i, j, q + 2] = (coords[t, 1] - col) * scale
        q = n_a + 3 + 3 * n_t
        for j2 in range(n_a):
            if j2 != j:
                out[i, j, q] = (coords[pos[i, j2], 0] - row) * scale
                out[i, j, q + 1] = (coords[pos[i, j2], 1] - col) * scale
                q += 2
        for d in range(4):
            out[i, j, dim - 4 + d] = neighbours[cell, d]


@njit(cache=True)
def treasure_step(
    acts: np.ndarray,
    pos: np.ndarray,
    tcell: np.ndarray,
    collected: np.ndarray,
    ep_len: np.ndarray,
    ep_return: np.ndarray,
    move: np.ndarray,
    event_reward: np.ndarray,
    treasure_reward: float,
    shared: bool,
    max_cycles: int,
    coords: np.ndarray,
    neighbours: np.ndarray,
    book_tail: np.ndarray,
    scale: float,
    egocentric: bool,
    obs: np.ndarray,
    rew: np.ndarray,
    done: np.ndarray,
    term: np.ndarray,
    ev: np.ndarray,
    slot_collected: np.ndarray,
) -> int:
    """One step of every team (agents move in index order); returns the number of finished episodes.

    State (updated): ``pos (n, n_agents)`` cells, ``tcell (n, n_treasures)`` (sentinel once collected),
    ``collected (n,)``, ``ep_len (n,)``, ``ep_return (n,)`` team return. ``move (n_cells, n_actions, 2)``:
    next cell and event code (0 move, 1 wall, 2 obstacle; 3 = treasure is set here). Outputs: ``obs
    (n, n_agents, dim)`` float32, zeroed by the caller, after the step (a finished episode's terminal
    observation: the caller resets that team), ``rew``/``ev``/``slot_collected`` per slot
    ``(n * n_agents,)``, ``done``/``term`` ``(n,)``. Finished teams keep their final state until the caller
    resets them. Returns ``-1 - s`` (nothing changed) if slot ``s``'s action is out of range.
    """
    bad = first_invalid_action(acts, move.shape[1])
    if bad >= 0:
        return -1 - bad
    n, n_a = pos.shape
    n_t = tcell.shape[1]
    n_cells = coords.shape[0] - 1
    keys = np.empty(n_t, dtype=np.int64)
    n_done = 0
    for i in range(n):
        total = 0
        for j in range(n_a):
            s = i * n_a + j
            nxt = move[pos[i, j], acts[s], 0]
            e = move[pos[i, j], acts[s], 1]
            found = 0
            if e == 0:
                pos[i, j] = nxt
                for k in range(n_t):
                    if tcell[i, k] == nxt:
                        tcell[i, k] = n_cells
                        found += 1
                        e = 3
            ev[s] = e
            rew[s] = event_reward[e]
            if not shared:
                rew[s] += treasure_reward * found
            total += found
        collected[i] += total
        team = 0.0
        for j in range(n_a):
            s = i * n_a + j
            if shared:
                rew[s] += treasure_reward * total
            team += rew[s]
            slot_collected[s] = collected[i]
        ep_return[i] += team
        ep_len[i] += 1
        t = collected[i] == n_t
        term[i] = t
        done[i] = t or ep_len[i] >= max_cycles
        if done[i]:
            n_done += 1
        _treasure_obs(i, pos, tcell, ep_len, coords, neighbours, book_tail, scale, egocentric, max_cycles, obs,
                      keys)
    return n_done


@njit(cache=True)
def treasure_reset(
    envs: np.ndarray,
    picks: np.ndarray,
    free: np.ndarray,
    pos: np.ndarray,
    tcell: np.ndarray,
    treasure: np.ndarray,
    collected: np.ndarray,
    ep_len: np.ndarray,
    ep_return: np.ndarray,
    coords: np.ndarray,
    neighbours: np.ndarray,
    book_tail: np.ndarray,
    scale: float,
    egocentric: bool,
    max_cycles: int,
    obs: np.ndarray,
) -> None:
    """Reset teams ``envs (m,)``: agents then treasures on the free cells ``free[picks] (m, n_agents +
    n_treasures)``; ``treasure`` keeps the initial treasure cells; rewrite the teams' observation rows."""
    n_a, n_t = pos.shape[1], tcell.shape[1]
    keys = np.empty(n_t, dtype=np.int64)
    for q in range(envs.shape[0]):
        i = envs[q]
        for j in range(n_a):
            pos[i, j] = free[picks[q, j]]
        for k in range(n_t):
            tcell[i, k] = treasure[i, k] = free[picks[q, n_a + k]]
        collected[i] = 0
        ep_len[i] = 0
        ep_return[i] = 0.0
        obs[i] = 0.0
        _treasure_obs(i, pos, tcell, ep_len, coords, neighbours, book_tail, scale, egocentric, max_cycles, obs,
                      keys)
