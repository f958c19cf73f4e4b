"""Baselines for the PettingZoo learning benchmarks: random play, and a scripted controller for
``mpe2.simple_spread_v3`` (each agent heads for its landmark of the assignment that minimises the summed distance).

Both act through :func:`sbagents.multiagent.team_eval.run_team_episodes` on the same team VecEnvs the trained
models are evaluated on, so their returns compare with the models' directly. A helper of
:mod:`benchmarks.learning.pettingzoo_learning` (whose sections show these baselines), not a benchmark of its own::

    baseline_summary("mpe2.simple_spread_v3", {}, "scripted", 300, 10_000, lambda _v: spread_assignment_actor(3))
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from sbagents.callbacks.episodes import stateless
from sbagents.core.team_options import TeamOptions
from sbagents.multiagent.factory import ParallelEnvFactory
from sbagents.multiagent.groups import team_vec_envs
from sbagents.multiagent.team_eval import Actor, run_team_episodes, slot_agents, team_summary

#: Discrete simple_spread actions: no-op, -x, +x, -y, +y.
SPREAD_MOVES = np.array([[0.0, 0.0], [-1.0, 0.0], [1.0, 0.0], [0.0, -1.0], [0.0, 1.0]])


def random_actor(venv: VecEnv, seed: int) -> Actor:
    """Uniform random actions for every slot of ``venv``."""
    space = venv.action_space
    space.seed(seed)
    return lambda obs: np.stack([space.sample() for _ in range(venv.num_envs)])


def spread_assignment_actor(n_agents: int = 3, gain: float = 2.0, damping: float = 0.4) -> Actor:
    """The scripted simple_spread controller for a shared (one-group) team VecEnv of ``n_agents`` agents.

    From its own observation ``[vel(2), pos(2), landmarks - pos (2N), others - pos (2(N-1)), comm]`` each agent
    finds the agent-to-landmark assignment with the least summed distance (all agents find the same one) and takes
    the move closest to the PD command ``gain * (target - pos) - damping * vel``, or no move near its target.
    """
    perms = [list(p) for p in itertools.permutations(range(n_agents))]

    def act(obs: np.ndarray) -> np.ndarray:
        actions = np.zeros(len(obs), dtype=np.int64)
        for k, o in enumerate(obs):
            j = k % n_agents  # this agent's index; the others follow in env order without it
            vel, landmarks = o[0:2], o[4:4 + 2 * n_agents].reshape(n_agents, 2)
            others = o[4 + 2 * n_agents:4 + 2 * n_agents + 2 * (n_agents - 1)].reshape(n_agents - 1, 2)
            rel = np.insert(others, j, np.zeros(2), axis=0)  # every agent's position relative to this one
            dist = np.linalg.norm(landmarks[None, :, :] - rel[:, None, :], axis=2)  # (agent, landmark)
            best = min(perms, key=lambda p: sum(dist[a, p[a]] for a in range(n_agents)))
            command = gain * landmarks[best[j]] - damping * vel
            if np.linalg.norm(command) < 0.05:
                continue
            actions[k] = int(np.argmax(SPREAD_MOVES[1:] @ command)) + 1
        return actions

    return act


def baseline_summary(source: str, env_kwargs: dict[str, Any], policy: str, episodes: int, seed: int,
                     actor_for: Callable[[VecEnv], Actor] | None = None) -> dict[str, Any]:
    """:func:`team_summary` of ``episodes`` team episodes (first reset seeded ``seed``) with every group random
    (``policy="random"``) or acting with ``actor_for(venv)``, on a one-copy team VecEnv per agent (``per_agent``)."""
    factory = ParallelEnvFactory(source, (), env_kwargs, [])
    options = TeamOptions("shared" if actor_for is not None else "per_agent")
    venvs = team_vec_envs(factory, 1, options)
    try:
        actors = {g: (actor_for(v) if actor_for is not None else random_actor(v, seed + i))
                  for i, (g, v) in enumerate(venvs.items())}
        episodes_run = run_team_episodes(venvs, {g: stateless(a) for g, a in actors.items()}, episodes, seed)
        summary = team_summary(episodes_run, {g: slot_agents(v, g) for g, v in venvs.items()})
    finally:
        next(iter(venvs.values())).close()
    summary["policy"] = policy
    return summary
