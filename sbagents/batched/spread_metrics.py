"""Team metrics of ``mpe2.simple_spread_v3`` that explain a score: collisions and landmarks covered.

Definitions (one for every path that builds simple spread):

- ``collisions``: colliding agent *pairs* per step (mpe2's ``is_collision``: two distinct agents closer than the sum
  of their sizes), counted after every step's move and summed over the episode. A pair counts once (the reward's
  local term counts it twice: -1 for each of its two agents).
- ``landmarks_covered``: landmarks whose nearest agent is within :data:`COVER_RADIUS` (distance ``<= 0.1``) at the
  episode's last step (``0 .. N``).
- ``landmarks_covered_mean``: the same count averaged over the episode's steps.

They are declared as episode metrics (:data:`SPREAD_METRICS`, ``metadata["info_metrics"]``, rule ``last``) and
reported in every agent's info at the episode's last step only (no per-step info: the batched VecEnv stays as fast as
before), so :class:`~sbagents.multiagent.env_copy.EnvCopy`, the team ``episode`` info, the monitor file and
:func:`~sbagents.multiagent.team_eval.team_summary` (``metrics``) carry them. Three paths report the same numbers:
:class:`~sbagents.batched.simple_spread.BatchedSimpleSpreadVecEnv` (vectorized, from the arrays it steps),
:class:`~sbagents.batched.spread_env.SimpleSpreadParallelEnv` (its one-copy view) and mpe2's own env wrapped in
:class:`SpreadMetricsWrapper` (an observer that reads mpe2's world after each step; what
:func:`sbagents.core.env_names.make_parallel_env` builds when the array env does not reproduce the kwargs). All use
:func:`pair_distances`, :func:`landmark_distances` and :func:`step_counts`, so their numbers are identical.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pettingzoo import ParallelEnv
from pettingzoo.utils.wrappers import BaseParallelWrapper

#: A landmark is covered when its nearest agent is at most this far from it.
COVER_RADIUS = 0.1
#: The declared episode metrics (``metadata["info_metrics"]``): every value is reported at the last step.
SPREAD_METRICS: dict[str, str] = {"collisions": "last", "landmarks_covered": "last", "landmarks_covered_mean": "last"}


def pair_distances(pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Agent-pair offsets ``p_i - p_j`` ``(..., N, N, 2)`` and distances ``(..., N, N)`` of positions
    ``(..., N, 2)`` (mpe2's ``sqrt(sum(square(delta)))``, in its order of operations)."""
    delta = pos[..., :, None, :] - pos[..., None, :, :]
    return delta, np.sqrt(np.square(delta[..., 0]) + np.square(delta[..., 1]))


def landmark_distances(pos: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """Each landmark's distance to its nearest agent ``(..., L)``, from agent positions ``(..., N, 2)`` and landmark
    positions ``(..., L, 2)`` (mpe2's ``global_reward`` distances)."""
    to_lm = pos[..., :, None, :] - landmarks[..., None, :, :]  # (..., agent, landmark, 2)
    return np.sqrt(np.square(to_lm[..., 0]) + np.square(to_lm[..., 1])).min(axis=-2)  # type: ignore[no-any-return]


def step_counts(hits: np.ndarray, closest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One step's colliding pairs and covered landmarks.

    :param hits: ``(..., N, N)`` bool, agent ``i`` collides with agent ``j`` (symmetric, false on the diagonal).
    :param closest: ``(..., L)`` each landmark's distance to its nearest agent.
    :return: colliding pairs ``(...)`` and covered landmarks ``(...)``, int64.
    """
    pairs = hits.sum(axis=(-2, -1)) // 2
    covered = (closest <= COVER_RADIUS).sum(axis=-1)
    return pairs.astype(np.int64), covered.astype(np.int64)


def hit_thresholds(sizes: np.ndarray) -> np.ndarray:
    """``(N, N)`` collision distances ``size_i + size_j`` (0 on the diagonal: an agent never collides with itself)."""
    sizes = np.asarray(sizes, dtype=np.float64)
    table = sizes[:, None] + sizes[None, :]
    np.fill_diagonal(table, 0.0)
    return table


def episode_metrics(collisions: int, covered: int, covered_sum: int, length: int) -> dict[str, Any]:
    """The info values of :data:`SPREAD_METRICS` at an episode's end (Python numbers)."""
    return {"collisions": int(collisions), "landmarks_covered": int(covered),
            "landmarks_covered_mean": float(covered_sum) / max(int(length), 1)}


class SpreadMetricsWrapper(BaseParallelWrapper):  # type: ignore[misc]
    """mpe2's simple spread ``ParallelEnv`` plus :data:`SPREAD_METRICS` (an observer: observations, rewards and
    dynamics are untouched).

    :param env: ``mpe2.simple_spread_v3.parallel_env(...)`` (anything whose ``unwrapped.world`` has ``agents`` and
        ``landmarks`` with ``size`` and ``state.p_pos``).
    """

    def __init__(self, env: ParallelEnv) -> None:
        super().__init__(env)
        self.metadata = {**dict(getattr(env, "metadata", None) or {}), "info_metrics": dict(SPREAD_METRICS)}
        self._start()

    def _start(self) -> None:
        self._collisions = 0
        self._covered_sum = 0
        self._length = 0

    # PettingZoo's ParallelEnv declares these as attributes, so the base wrapper's __getattr__ never forwards them
    @property
    def agents(self) -> list[Any]:  # type: ignore[override]
        return self.env.agents  # type: ignore[no-any-return]

    @agents.setter
    def agents(self, agents: list[Any]) -> None:
        self.env.agents = agents

    @property
    def possible_agents(self) -> list[Any]:  # type: ignore[override]
        return self.env.possible_agents  # type: ignore[no-any-return]

    @property
    def render_mode(self) -> str | None:  # type: ignore[override]
        return getattr(self.env, "render_mode", None)

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[dict[Any, Any], dict[Any, dict[str, Any]]]:
        """Reset the env and the episode's counts."""
        result = self.env.reset(seed=seed, options=options)
        self._start()
        return result  # type: ignore[no-any-return]

    def step(self, actions: dict[Any, Any]) -> tuple[dict[Any, Any], dict[Any, float], dict[Any, bool],
                                                      dict[Any, bool], dict[Any, dict[str, Any]]]:
        """Step the env, count this step's collisions and covered landmarks; at the episode's end every agent's info
        gets the episode's :data:`SPREAD_METRICS`."""
        acting = list(self.env.agents)
        obs, rewards, terms, truncs, infos = self.env.step(actions)
        world = self.env.unwrapped.world  # type: ignore[attr-defined]
        pos = np.array([a.state.p_pos for a in world.agents], dtype=np.float64)
        landmarks = np.array([lm.state.p_pos for lm in world.landmarks], dtype=np.float64)
        _, dist = pair_distances(pos)
        hits = dist < hit_thresholds(np.array([a.size for a in world.agents]))
        pairs, covered = step_counts(hits, landmark_distances(pos, landmarks))
        self._collisions += int(pairs)
        self._covered_sum += int(covered)
        self._length += 1
        ended = not self.env.agents or all(terms.get(a, False) or truncs.get(a, False) for a in acting)
        if ended:
            stats = episode_metrics(self._collisions, int(covered), self._covered_sum, self._length)
            infos = {a: {**dict(infos.get(a, {})), **stats} for a in acting}
        return obs, rewards, terms, truncs, infos


def spread_metrics_env(env: ParallelEnv) -> ParallelEnv:
    """``env`` with :data:`SPREAD_METRICS` (``env`` itself when it declares them already, as the array env does)."""
    if dict((getattr(env, "metadata", None) or {}).get("info_metrics") or {}) == SPREAD_METRICS:
        return env
    return SpreadMetricsWrapper(env)
