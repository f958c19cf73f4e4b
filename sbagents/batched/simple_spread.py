"""Batched MPE simple spread (``mpe2.simple_spread_v3``, discrete actions): the parameter-sharing team VecEnv of
``n_envs`` copies, stepped as numpy arrays.

Equivalent, step by step, to the reference path of a PettingZoo env with ``policies: shared`` (no agent id, local
critic): :func:`sbagents.multiagent.groups.team_vec_envs` over ``n_envs`` copies of
``mpe2.simple_spread_v3.parallel_env(**env_kwargs)`` (the same as
:func:`~sbagents.multiagent.parameter_sharing.make_parameter_sharing_vec_env`). Slot ``k`` is agent ``k % N`` of copy
``k // N``. Same ``float32`` observations ``[self vel, self pos, landmark rel pos, other agents' rel pos,
communication (always zero: the agents are silent)]``, ``float32`` rewards, dones, infos (``{}`` every step; at the
episode end, step ``max_cycles``, ``terminal_observation`` and ``TimeLimit.truncated=True`` in every slot and the team
``episode = {"r", "l", "t", <metrics>}`` in each copy's first slot, the declared team metrics
:data:`~sbagents.batched.spread_metrics.SPREAD_METRICS` (collisions, landmarks covered) in every slot of the last
step; its agents never leave, so no ``sbagents_acted`` flag), auto-reset, seeding (copy ``i`` is reset with
``seed + i``), ``reset()`` (pending seeds used once, options ignored as mpe2 ignores them), and the team monitor file
``<monitor_dir>/0.monitor.csv`` (one row per team episode with the metrics' columns, the header's ``env_id`` read
from the env's metadata).

How: the world state of all copies lives in arrays (agent positions and velocities ``(n_envs, N, 2)``, landmark
positions ``(n_envs, N, 2)``, float64 as in mpe2) and every step does mpe2's arithmetic with numpy ufuncs in mpe2's
order of operations: action decoding (``1..4`` -> ``-x, +x, -y, +y`` times the sensitivity 5), the softplus
collision force between agent pairs (``logaddexp`` with the contact margin), added to the action force in the order
mpe2's pair loop adds them, the damped Euler integration, the rewards (global: minus the sum over landmarks of the
closest agent's distance; local: -1 per colliding agent; blended with ``local_ratio``) and the observations cast to
``float32`` at the end. IEEE operations in the same order give the same bits, so the outputs equal the reference's
exactly (the tests allow 1e-5); episode returns are summed in float64 in the reference's order too.

Each copy owns a numpy ``Generator`` created as mpe2 creates its ``np_random`` (gymnasium's ``seeding.np_random``)
and draws a start state as mpe2's ``reset_world`` does: ``uniform(-1, 1)`` positions of the agents, then of the
landmarks (one call of shape ``(2N, 2)``: the same numbers as mpe2's per-entity calls). All copies start together
and every episode lasts exactly ``max_cycles`` steps, so they all end together: the episode end is one check per
step, and only then does Python loop over the copies (one generator call each).

Batchable kwargs: ``N``, ``local_ratio``, ``max_cycles``, ``dynamic_rescaling`` (rendering only), with
``continuous_actions``, ``benchmark_data``, ``curriculum`` and ``terminate_on_success`` false, no
``num_agent_neighbors``/``num_landmark_neighbors`` and no ``render_mode`` (:func:`unsupported_kwargs`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from gymnasium.utils import seeding
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn

from sbagents.batched.base import BatchedTeamVecEnv, check_batchable, unreproduced_kwargs
from sbagents.batched.spread_metrics import (
    SPREAD_METRICS,
    episode_metrics,
    landmark_distances,
    pair_distances,
    spread_metrics_env,
    step_counts,
)

#: The ``--env`` name (and the id :func:`sbagents.batched.make_batched_vec_env` takes).
SIMPLE_SPREAD_ID = "mpe2.simple_spread_v3"
#: PettingZoo sources (:class:`~sbagents.core.env_names.EnvRef.source`) this batched env reproduces.
SIMPLE_SPREAD_SOURCES: tuple[str, ...] = (SIMPLE_SPREAD_ID, f"{SIMPLE_SPREAD_ID}:parallel_env")
#: What the batched env supports, for error messages.
SIMPLE_SPREAD_SUPPORT = ("N, local_ratio, max_cycles, dynamic_rescaling; no continuous_actions, render_mode, "
                         "benchmark_data, curriculum, terminate_on_success or num_*_neighbors")

#: kwarg -> whether the batched env reproduces a value of it (the kwargs not listed: any valid value).
_REPRODUCED: dict[str, Callable[[Any], bool]] = {
    "continuous_actions": lambda v: not v,  # mpe2 tests these flags for truth
    "benchmark_data": lambda v: not v,
    "curriculum": lambda v: not v,
    "terminate_on_success": lambda v: not v,
    "render_mode": lambda v: v is None,
    "num_agent_neighbors": lambda v: v is None,
    "num_landmark_neighbors": lambda v: v is None,
}


def unsupported_kwargs(env_kwargs: Mapping[str, Any]) -> list[str]:
    """The env kwargs whose values the batched env does not reproduce, as ``key=value`` (empty: batchable).

    Unknown keys and invalid values of the supported keys are left to the env's constructor (it raises as the
    reference does).
    """
    return unreproduced_kwargs(env_kwargs, _REPRODUCED)


class BatchedSimpleSpreadVecEnv(BatchedTeamVecEnv):
    """``n_envs`` simple-spread teams as one parameter-sharing SB3 ``VecEnv`` (``n_envs * N`` slots).

    :param n_envs: number of env copies (teams).
    :param env_kwargs: keyword arguments of ``mpe2.simple_spread_v3.parallel_env`` (see :func:`unsupported_kwargs`).
    :param monitor_path: if given, team episodes are written to this SB3 monitor file (``<path>.monitor.csv``:
        ``r`` team return, ``l``, ``t``), like the reference.
    :raises ValueError: ``n_envs < 1``, or kwargs the batched env does not reproduce.

    Observations have shape ``(n_envs * N, 6 N)`` float32; actions ``(n_envs * N,)`` in ``0..4``.
    """

    def __init__(
        self, n_envs: int, env_kwargs: dict[str, Any] | None = None, monitor_path: str | None = None
    ) -> None:
        from mpe2 import simple_spread_v3  # optional dependency (the pettingzoo-envs extra)

        kwargs = dict(env_kwargs or {})
        check_batchable(n_envs, unsupported_kwargs(kwargs), SIMPLE_SPREAD_ID, SIMPLE_SPREAD_SUPPORT)
        # the template (mpe2's env as sbagents builds it: with the metrics observer); validates the kwargs as the
        # reference does
        env: Any = spread_metrics_env(simple_spread_v3.parallel_env(**kwargs))
        env.reset(seed=0)  # a reset env, so that state() and friends work on it
        raw = env.unwrapped
        world = raw.world
        self._check_world(world)
        self.possible_agents = list(env.possible_agents)
        self.n_agents, self.n_landmarks = len(world.agents), len(world.landmarks)
        self.max_cycles, self.local_ratio = raw.max_cycles, raw.local_ratio
        n, n_a, n_l = n_envs, self.n_agents, self.n_landmarks
        self._load_constants(world)
        self._slot_agent = np.tile(np.arange(n_a), n)  # the agent index of every slot
        # others[j]: the other agents in index order; rel_index[j]: landmarks then those others, as indices into
        # the entity array ``concat(landmarks, agents)``
        others = np.array([[o for o in range(n_a) if o != j] for j in range(n_a)], dtype=np.int64).reshape(n_a, -1)
        self._rel_index = np.concatenate([np.broadcast_to(np.arange(n_l), (n_a, n_l)), n_l + others], axis=1)
        obs_space = env.observation_space(self.possible_agents[0])
        self._dim = int(obs_space.shape[0])
        n_rel = n_l + n_a - 1
        self._comm = 4 + 2 * n_rel  # where the (zero) communication part starts
        if self._dim != self._comm + self._dim_c * (n_a - 1):
            raise NotImplementedError(f"unexpected simple_spread observation size {self._dim}")
        self._pos = np.zeros((n, n_a, 2), dtype=np.float64)
        self._vel = np.zeros((n, n_a, 2), dtype=np.float64)
        self._lm = np.zeros((n, n_l, 2), dtype=np.float64)
        self._delta = np.zeros((n, n_a, n_a, 2), dtype=np.float64)  # see _geometry
        self._dist = np.zeros((n, n_a, n_a), dtype=np.float64)
        self._returns = np.zeros((n, n_a), dtype=np.float64)  # per-agent episode returns, as the reference sums
        self._collisions = np.zeros(n, dtype=np.int64)  # colliding pairs, summed over the episode's steps
        self._covered = np.zeros(n, dtype=np.int64)  # landmarks covered after the last step
        self._covered_sum = np.zeros(n, dtype=np.int64)  # landmarks covered, summed over the episode's steps
        self._length = 0  # steps of the current episode: the same in every copy (they start and end together)
        self._rngs: list[np.random.Generator | None] = [None] * n
        super().__init__(n * n_a, n_a, env, obs_space, env.action_space(self.possible_agents[0]), monitor_path,
                         str(env.metadata.get("name", "team")),  # the reference's monitor header, read as it reads it
                         tuple(SPREAD_METRICS))
        self._n_actions = int(self.action_space.n)  # type: ignore[attr-defined]

    # ------------------------------------------------------------------ world constants
    @staticmethod
    def _check_world(world: Any) -> None:
        """The world is the one this module reproduces (guards against a changed mpe2)."""
        agents, landmarks = world.agents, world.landmarks
        ok = (all(a.movable and a.silent and a.collide and a.max_speed is None and not a.u_noise
                  and a.action_callback is None for a in agents)
              and all(not lm.movable and not lm.collide for lm in landmarks) and world.dim_p == 2)
        if not ok:
            raise NotImplementedError("this mpe2 simple_spread world differs from the one sbagents batches")

    def _load_constants(self, world: Any) -> None:
        """Physics constants and per-agent tables, read from the template's world."""
        agents = world.agents
        self._dt, self._damping = world.dt, world.damping
        self._contact_force, self._margin = world.contact_force, world.contact_margin
        self._dim_c = world.dim_c
        self._dist_min = np.array([[a.size + b.size for b in agents] for a in agents], dtype=np.float64)
        self._diag = np.arange(len(agents))
        self._hit_min = self._dist_min.copy()
        self._hit_min[self._diag, self._diag] = 0.0  # an agent is at distance 0 from itself: never a hit
        self._mass = np.array([a.mass for a in agents], dtype=np.float64)[None, :, None]
        # u per (agent, action): mpe2's discrete decoding (1: -x, 2: +x, 3: -y, 4: +y) times the sensitivity
        unit = np.array([[0.0, 0.0], [-1.0, 0.0], [1.0, 0.0], [0.0, -1.0], [0.0, 1.0]])
        self._u_table = np.stack([unit * (5.0 if a.accel is None else a.accel) for a in agents])

    # ------------------------------------------------------------------ reset
    def _start_episodes(self) -> None:
        """Draw every copy's start state from its generator (mpe2's ``reset_world`` draws) and zero the episode."""
        shape = (self.n_agents + self.n_landmarks, 2)
        starts = np.stack([rng.uniform(-1, +1, shape) for rng in self._rngs])  # type: ignore[union-attr]
        self._pos[:] = starts[:, : self.n_agents]
        self._lm[:] = starts[:, self.n_agents :]
        self._vel[:] = 0.0
        self._returns[:] = 0.0
        self._collisions[:] = 0
        self._covered[:] = 0
        self._covered_sum[:] = 0
        self._length = 0
        self._geometry()

    def reset(self) -> VecEnvObs:
        """Reset every copy (pending seeds are used once); returns ``(num_envs, obs_dim)`` float32."""
        for i in range(self.n_envs):
            seed = self._seeds[i * self.n_agents]
            if seed is not None or self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(seed)
        self._start_episodes()
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return self._observe().reshape(self.num_envs, self._dim)

    # ------------------------------------------------------------------ step
    def _observe(self) -> np.ndarray:
        """Observations ``(n_envs, N, obs_dim)`` float32 of the current state (mpe2's layout and arithmetic)."""
        n, n_a = self.n_envs, self.n_agents
        pos = self._pos
        obs = np.zeros((n, n_a, self._dim), dtype=np.float32)
        obs[:, :, 0:2] = self._vel
        obs[:, :, 2:4] = pos
        entities = np.concatenate([self._lm, pos], axis=1)  # (n, n_l + n_a, 2)
        rel = entities[:, self._rel_index] - pos[:, :, None, :]  # (n, n_a, n_l + n_a - 1, 2)
        obs[:, :, 4 : self._comm] = rel.reshape(n, n_a, -1)
        return obs

    def _geometry(self) -> None:
        """Agent-pair offsets ``p_i - p_j`` ``(n_envs, N, N, 2)`` and distances ``(n_envs, N, N)`` of the current
        positions (mpe2's ``sqrt(sum(square(delta)))``): the collision forces of the next step and the collision
        penalties of this one use them."""
        self._delta, self._dist = pair_distances(self._pos)

    def _forces(self) -> np.ndarray:
        """Action plus collision forces ``(n_envs, N, 2)``, summed in the order of mpe2's pair loop."""
        n, n_a = self.n_envs, self.n_agents
        force = self._u_table[self._slot_agent, self._actions].reshape(n, n_a, 2)
        if n_a < 2:
            return force
        delta, dist, k = self._delta, self._dist, self._margin
        with np.errstate(divide="ignore", invalid="ignore"):  # i == j: 0 / 0, zeroed below
            penetration = np.logaddexp(0, -(dist - self._dist_min) / k) * k
            pair = self._contact_force * delta / dist[..., None] * penetration[..., None]
        pair[:, self._diag, self._diag] = 0.0
        # mpe2 adds agent i's pair forces to its action force in the order of j (pairs (j, i), then (i, j));
        # the force on b of pair (a, b) is the negated force on a, which equals the one computed from p_b - p_a
        for j in range(n_a):
            force = pair[:, :, j] + force
        return force

    def step_wait(self) -> VecEnvStepReturn:
        self._checked_actions(self._rngs[0] is not None, self._n_actions)
        n, n_a, k = self.n_envs, self.n_agents, self.num_envs
        force = self._forces()
        # integrate (mpe2's World.integrate_state)
        self._pos += self._vel * self._dt
        self._vel = self._vel * (1 - self._damping)
        self._vel += (force / self._mass) * self._dt
        self._geometry()
        rewards64 = self._rewards()
        self.last_rewards = rewards64  # (n_envs, N) float64, as mpe2 returns them (the VecEnv's are float32)
        self._returns += rewards64
        self._length += 1
        obs = self._observe()
        rewards = rewards64.astype(np.float32).reshape(k)
        if self._length < self.max_cycles:
            return obs.reshape(k, self._dim), rewards, np.zeros(k, dtype=bool), [{} for _ in range(k)]
        infos = self._finish_episodes(obs)
        return self._observe().reshape(k, self._dim), rewards, np.ones(n * n_a, dtype=bool), infos

    def _rewards(self) -> np.ndarray:
        """This step's rewards ``(n_envs, N)`` float64 (mpe2's ``global_reward``, ``reward`` and their blend); counts
        the step's team metrics too."""
        closest = landmark_distances(self._pos, self._lm)  # (n, landmark)
        total = np.zeros(self.n_envs)
        for m in range(self.n_landmarks):  # mpe2: rew = 0; rew -= min(dists) per landmark, in order
            total = total - closest[:, m]
        hits = self._dist < self._hit_min  # mpe2's is_collision, never with itself
        local = -hits.sum(axis=1).astype(np.float64)  # -1.0 per other agent in collision: exact integers
        pairs, self._covered = step_counts(hits, closest)
        self._collisions += pairs
        self._covered_sum += self._covered
        lr = self.local_ratio
        return total[:, None] * (1 - lr) + local * lr  # type: ignore[no-any-return]

    def _finish_episodes(self, terminal: np.ndarray) -> list[dict[str, Any]]:
        """Episode-end infos (terminal observations, truncation, team ``episode``), monitor rows and the reset of
        every copy (they all end together, at ``max_cycles``)."""
        n_a = self.n_agents
        rows = list(terminal.reshape(self.num_envs, self._dim))
        length = self._length
        stats = [episode_metrics(c, v, s, length) for c, v, s in zip(  # noqa: B905 - arrays of n_envs
            self._collisions.tolist(), self._covered.tolist(), self._covered_sum.tolist())]
        infos: list[dict[str, Any]] = [{**stats[k // n_a], "terminal_observation": row, "TimeLimit.truncated": True}
                                       for k, row in enumerate(rows)]
        team = np.zeros(self.n_envs)
        for j in range(n_a):  # the reference: sum(per-agent returns) in agent order, from 0
            team = team + self._returns[:, j]
        seconds = self._monitor_seconds()
        for i, r in enumerate(team.tolist()):
            ep = {"r": round(r, 6), "l": length, "t": seconds, **stats[i]}
            infos[i * n_a]["episode"] = ep
            if self._writer is not None:
                self._writer.write_row(ep)
        self._start_episodes()
        return infos

    # ------------------------------------------------------------------ attributes
    def _sync(self, env_index: int) -> None:
        env = self.template
        raw = env.unwrapped
        i = env_index
        for j, agent in enumerate(raw.world.agents):
            agent.state.p_pos = self._pos[i, j].copy()
            agent.state.p_vel = self._vel[i, j].copy()
            agent.state.c = np.zeros(self._dim_c)
        for m, landmark in enumerate(raw.world.landmarks):
            landmark.state.p_pos = self._lm[i, m].copy()
            landmark.state.p_vel = np.zeros(2)
        raw.steps = self._length
        raw.agents = list(self.possible_agents)
        env.agents = list(self.possible_agents)
