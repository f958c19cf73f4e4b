"""Parameter sharing: a PettingZoo ``ParallelEnv`` -> one SB3 ``VecEnv`` whose slots are all its agents (one
policy drives every agent).

:class:`ParameterSharingVecEnv` replaces SuperSuit's ``pettingzoo_env_to_vec_env_v1`` + ``concat_vec_envs_v1`` and
avoids its traps: time-outs carry ``TimeLimit.truncated`` (so SB3 bootstraps), ``seed()`` works, episode
statistics are team statistics counted once per team episode, and agents may leave early or arrive later (their
absent slots are marked ``sbagents_acted: False`` and left out of learning by :mod:`sbagents.multiagent.masking`,
instead of SuperSuit's ``black_death`` zero observations). Agents with different Box observation spaces are padded
to one space with an agent-type feature (:class:`~sbagents.multiagent.group_env.ObsLayout`).

Slot layout: ``num_envs = n_envs * n_agents``; slot ``k`` is agent ``possible_agents[k % n_agents]`` of copy
``k // n_agents``. It is the one-group case of :class:`~sbagents.multiagent.group_env.GroupVecEnv`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from pettingzoo import ParallelEnv

from sbagents.core.run_dir import SHARED_GROUP
from sbagents.multiagent.group_env import GroupVecEnv, ObsLayout
from sbagents.multiagent.joint import JointStepper
from sbagents.multiagent.team import Team, monitor_path


class ParameterSharingVecEnv(GroupVecEnv):
    """All agents of ``len(env_fns)`` copies of a parallel env as one SB3 ``VecEnv``.

    :param env_fns: zero-argument constructors of the ``ParallelEnv`` copies (picklable ones for ``subproc``).
    :param monitor_path: if given, an SB3 monitor file with one row per team episode (``r`` team return, ``l``,
        ``t`` and the env's declared ``info_metrics``).
    :param agent_id: append a one-hot agent id to every observation.
    :param centralized: observations are ``Dict(obs, state)`` with the env's ``state()`` for a centralized critic.
    :param subproc: run the copies in worker processes.

    Observations have shape ``(n_envs * n_agents, *obs_shape)``; actions ``(n_envs * n_agents, ...)``. When a copy's
    episode ends every slot of it gets ``terminal_observation`` and ``TimeLimit.truncated`` and the copy is reset;
    the slot of its first agent also gets ``episode`` (team return, length, seconds, declared metrics).
    """

    def __init__(
        self, env_fns: Sequence[Callable[[], ParallelEnv]], monitor_path: str | None = None, agent_id: bool = False,
        centralized: bool = False, subproc: bool = False,
    ) -> None:
        team = Team(env_fns, monitor_path, subproc=subproc, with_state=centralized)
        agents = list(team.possible_agents)
        layout = ObsLayout(agents, team.observation_spaces, agent_id, team.state_space)
        super().__init__(JointStepper(team, {SHARED_GROUP: agents}), SHARED_GROUP, layout)


def make_parameter_sharing_vec_env(
    env_fn: Callable[..., ParallelEnv],
    n_envs: int = 1,
    seed: int | None = None,
    env_kwargs: dict[str, Any] | None = None,
    monitor_dir: str | None = None,
    **options: Any,
) -> ParameterSharingVecEnv:
    """Build a :class:`ParameterSharingVecEnv` of ``n_envs`` copies of ``env_fn(**env_kwargs)``.

    :param env_fn: constructor of a ``ParallelEnv`` (e.g. ``treasure_hunt_v0.parallel_env``).
    :param n_envs: number of copies (the VecEnv has ``n_envs * n_agents`` slots).
    :param seed: copy ``k`` is reset with ``seed + k`` on the first reset (``None``: random).
    :param env_kwargs: keyword arguments for ``env_fn``.
    :param monitor_dir: if given, team episodes are logged to ``<monitor_dir>/0.monitor.csv``.
    :param options: ``agent_id``, ``centralized``, ``subproc`` of :class:`ParameterSharingVecEnv`.
    """
    fns = [_Factory(env_fn, dict(env_kwargs or {})) for _ in range(n_envs)]
    vec = ParameterSharingVecEnv(fns, monitor_path=monitor_path(monitor_dir), **options)
    if seed is not None:
        vec.seed(seed)
    return vec


class _Factory:
    """``env_fn(**kwargs)`` as a picklable zero-argument callable (for worker processes)."""

    def __init__(self, env_fn: Callable[..., ParallelEnv], kwargs: dict[str, Any]) -> None:
        self.env_fn, self.kwargs = env_fn, kwargs

    def __call__(self) -> ParallelEnv:
        return self.env_fn(**self.kwargs)
