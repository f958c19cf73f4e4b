"""Scripted references and mixed teams for the mpe2 envs of the ``pettingzoo-defaults`` benchmark
(``simple_reference_v3``, ``simple_push_v3``, ``simple_adversary_v3``).

A *side* is a set of agents scored together (:data:`SIDES`): the whole team of the cooperative
``simple_reference``, the adversary and the good agents of the mixed envs. A side's return is the sum of its agents'
returns. Each side can be played by the trained model, by uniform random actions or by a scripted controller
(:data:`SCRIPTS`), against the trained model's other side (:func:`mixed_actor`), on the same team VecEnvs the
evaluation uses. The scripts read each agent's own observation only (mpe2's layouts; the padded shared-policy
observation starts with it):

- ``simple_reference``: each agent says the colour index of the landmark its partner must reach (the communication
  part of its action) and moves to the landmark its partner names (no move until it has heard).
- ``simple_push``: the good agent heads for its goal landmark; the adversary (who does not know the goal) heads for
  the landmark nearest the good agent.
- ``simple_adversary``: of the two good agents the one nearer the goal heads for it, the other for the other
  landmark (a decoy); the adversary heads for its nearest landmark.

Moves: the discrete move whose direction is closest to ``gain * offset - damping * velocity`` (no move within 0.05).
A helper of :mod:`benchmarks.learning.pettingzoo_defaults`, not a benchmark of its own::

    summary = side_summary("mpe2.simple_push_v3", {"adversary_0": "scripted", "agent_0": "scripted"}, 100, 10_000)
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sbagents.callbacks.episodes import Policy
from sbagents.core.team_options import TeamOptions
from sbagents.multiagent.factory import ParallelEnvFactory
from sbagents.multiagent.groups import team_vec_envs
from sbagents.multiagent.team_eval import run_team_episodes, slot_agents, team_summary

#: Discrete mpe2 moves: no-op, -x, +x, -y, +y.
MOVES = np.array([[0.0, 0.0], [-1.0, 0.0], [1.0, 0.0], [0.0, -1.0], [0.0, 1.0]])

#: env -> side -> its agents.
SIDES: dict[str, dict[str, tuple[str, ...]]] = {
    "mpe2.simple_reference_v3": {"team": ("agent_0", "agent_1")},
    "mpe2.simple_push_v3": {"adversary": ("adversary_0",), "good": ("agent_0",)},
    "mpe2.simple_adversary_v3": {"adversary": ("adversary_0",), "good": ("agent_0", "agent_1")},
}

#: One copy's raw observations by agent -> every agent's action.
Script = Callable[[Mapping[str, np.ndarray]], dict[str, int]]


def move_toward(offset: np.ndarray, velocity: np.ndarray | None = None, gain: float = 2.0,
                damping: float = 0.4) -> int:
    """The discrete move (0..4) closest in direction to ``gain * offset - damping * velocity`` (0 when small)."""
    command = gain * np.asarray(offset, dtype=np.float64)
    if velocity is not None:
        command = command - damping * np.asarray(velocity, dtype=np.float64)
    if np.linalg.norm(command) < 0.05:
        return 0
    return int(np.argmax(MOVES[1:] @ command)) + 1


def reference_script(obs: Mapping[str, np.ndarray]) -> dict[str, int]:
    """simple_reference: ``[vel(2), landmarks(3x2), partner's goal colour(3), heard(10)]``; action
    ``move + 5 * word``."""
    actions = {}
    for agent, o in obs.items():
        landmarks, goal_colour, heard = o[2:8].reshape(3, 2), o[8:11], o[11:21]
        word = int(np.argmax(goal_colour)) if goal_colour.max() > 0 else 0
        move = move_toward(landmarks[int(np.argmax(heard))], o[0:2]) if heard.max() > 0 else 0
        actions[agent] = move + 5 * word
    return actions


def push_script(obs: Mapping[str, np.ndarray]) -> dict[str, int]:
    """simple_push: good ``[vel, goal(2), colour(3), landmarks(2x2), colours(2x3), adversary(2)]``, adversary
    ``[vel, landmarks(2x2), good agent(2)]``."""
    good, adv = obs["agent_0"], obs["adversary_0"]
    landmarks, other = adv[2:6].reshape(2, 2), adv[6:8]
    target = landmarks[int(np.argmin(np.linalg.norm(landmarks - other, axis=1)))]
    return {"adversary_0": move_toward(target, adv[0:2]), "agent_0": move_toward(good[2:4], good[0:2])}


def adversary_script(obs: Mapping[str, np.ndarray]) -> dict[str, int]:
    """simple_adversary: good ``[goal(2), landmarks(2x2), adversary(2), other good agent(2)]``, adversary
    ``[landmarks(2x2), good agents(2x2)]`` (no velocities)."""
    adv = obs["adversary_0"]
    landmarks = adv[0:4].reshape(2, 2)
    actions = {"adversary_0": move_toward(landmarks[int(np.argmin(np.linalg.norm(landmarks, axis=1)))])}
    for agent in ("agent_0", "agent_1"):
        o = obs[agent]
        goal, marks, mate = o[0:2], o[2:6].reshape(2, 2), o[8:10]
        decoy = marks[int(np.argmax(np.linalg.norm(marks - goal, axis=1)))]  # the landmark that is not the goal
        nearer = np.linalg.norm(goal) <= np.linalg.norm(goal - mate)
        actions[agent] = move_toward(goal if nearer else decoy)
    return actions


#: env -> its scripted controller.
SCRIPTS: dict[str, Script] = {"mpe2.simple_reference_v3": reference_script, "mpe2.simple_push_v3": push_script,
                              "mpe2.simple_adversary_v3": adversary_script}


def raw_obs_dims(env: str) -> dict[str, int]:
    """Each agent's own observation size (the padded shared observation starts with it)."""
    from sbagents.core.env_names import make_parallel_env

    par = make_parallel_env(env)
    try:
        return {str(a): int(np.prod(par.observation_space(a).shape)) for a in par.possible_agents}
    finally:
        par.close()


def mixed_actor(env: str, venv: VecEnv, agents: list[str], players: Mapping[str, str],
                model_act: Policy | None = None, seed: int = 0) -> Policy:
    """One shared-group actor whose agents play as ``players`` says: ``model``, ``random`` or ``scripted``.

    :param venv: the shared team VecEnv (slot ``k`` is ``agents[k % len(agents)]``); under ``VecNormalize`` the
        scripts read its original observations.
    :param model_act: the trained model's policy (needed when some agent plays ``model``; its state is carried).
    """
    n = len(agents)
    dims = raw_obs_dims(env)
    script = SCRIPTS[env]
    rng = np.random.default_rng(seed)
    n_actions = int(venv.action_space.n)  # type: ignore[attr-defined]
    unknown = set(players.values()) - {"model", "random", "scripted"}
    if unknown:
        raise ValueError(f"players must be model, random or scripted, got {sorted(unknown)}")

    def act(obs: np.ndarray, state: Any, episode_start: np.ndarray) -> tuple[np.ndarray, Any]:
        if model_act is not None:
            chosen, state = model_act(obs, state, episode_start)
            actions = np.asarray(chosen).copy()
        else:
            actions = np.zeros(len(obs), dtype=np.int64)
        raw = np.asarray(venv.get_original_obs() if isinstance(venv, VecNormalize) else obs)
        for c in range(len(obs) // n):
            copy = {a: np.asarray(raw[c * n + j][: dims[a]], dtype=np.float64) for j, a in enumerate(agents)}
            scripted = script(copy) if "scripted" in players.values() else {}
            for j, a in enumerate(agents):
                if players[a] == "random":
                    actions[c * n + j] = rng.integers(n_actions)
                elif players[a] == "scripted":
                    actions[c * n + j] = scripted[a]
        return actions, state

    return act


def side_returns(env: str, summary: Mapping[str, Any]) -> dict[str, float]:
    """Each side's mean return (the sum of its agents' mean returns) from a team summary."""
    per_agent = summary["metrics"]["per_agent_return"]
    return {side: float(sum(per_agent[a] for a in members)) for side, members in SIDES[env].items()}


def side_summary(env: str, players: Mapping[str, str], episodes: int, seed: int, copies: int = 8
                 ) -> dict[str, Any]:
    """:func:`team_summary` of ``episodes`` episodes on ``copies`` env copies (copy ``i``'s first reset seeded
    ``seed + i``) with no model: every agent random or scripted (``players``); plus ``sides``
    (:func:`side_returns`)."""
    venv = team_vec_envs(ParallelEnvFactory(env, (), {}, []), copies, TeamOptions("shared"))["shared"]
    try:
        actor = mixed_actor(env, venv, slot_agents(venv, "shared"), players, seed=seed)
        summary = team_summary(run_team_episodes({"shared": venv}, {"shared": actor}, episodes, seed))
    finally:
        venv.close()
    return {**summary, "sides": side_returns(env, summary)}
