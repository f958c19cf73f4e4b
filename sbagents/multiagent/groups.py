"""Which agents share a model: the groups of a team (``policies: shared | per_agent | per_group``), and the group
VecEnvs of one team (:func:`team_vec_envs`).

``per_group`` groups agents by name prefix (``adversary_0``, ``adversary_1`` -> ``adversary``; ``agent_0`` ->
``agent``), or by an explicit ``groups`` mapping that names every agent once.
"""

from __future__ import annotations

import re
from collections.abc import Callable

from pettingzoo import ParallelEnv

from sbagents.core.team_options import TeamOptions
from sbagents.errors import UsageError
from sbagents.multiagent.group_env import GroupVecEnv, ObsLayout
from sbagents.multiagent.joint import JointStepper
from sbagents.multiagent.parameter_sharing import SHARED_GROUP
from sbagents.multiagent.team import Team, monitor_path

_NUMBERED = re.compile(r"^(?P<prefix>.+?)_?\d+$")


def name_prefix(agent: str) -> str:
    """The group of an agent named ``<prefix>_<k>`` (``adversary_2`` -> ``adversary``), else the name itself."""
    match = _NUMBERED.match(agent)
    return match["prefix"] if match else agent


def team_groups(options: TeamOptions, agents: list[str]) -> dict[str, list[str]]:
    """Group name -> agents, in the env's agent order.

    :raises UsageError: an explicit mapping that misses an agent, names one twice or names an unknown one.
    """
    if options.policies == "shared":
        return {SHARED_GROUP: list(agents)}
    if options.policies == "per_agent":
        return {a: [a] for a in agents}
    if options.groups is None:
        groups: dict[str, list[str]] = {}
        for agent in agents:
            groups.setdefault(name_prefix(agent), []).append(agent)
        return groups
    named = [a for members in options.groups.values() for a in members]
    missing = [a for a in agents if a not in named]
    unknown = sorted(set(named) - set(agents))
    twice = sorted({a for a in named if named.count(a) > 1})
    if missing or unknown or twice:
        problems = [f"{what}: {', '.join(which)}" for what, which in
                    (("missing", missing), ("unknown", unknown), ("in two groups", twice)) if which]
        raise UsageError(f"groups must name every agent once ({'; '.join(problems)}); the env's agents: "
                         f"{', '.join(agents)}")
    return {g: [a for a in agents if a in members] for g, members in options.groups.items()}


def team_vec_envs(
    env_fn: Callable[[], ParallelEnv], n_envs: int, options: TeamOptions, seed: int | None = None,
    monitor_dir: str | None = None, subproc: bool = False,
) -> dict[str, GroupVecEnv]:
    """One team of ``n_envs`` copies of ``env_fn()`` and a VecEnv per group of its agents (they step together).

    :param options: the grouping, agent id and critic of the experiment.
    :param seed: copy ``k`` is reset with ``seed + k`` at the first reset (None: random).
    :param monitor_dir: if given, team episodes go to ``<monitor_dir>/0.monitor.csv``.
    :param subproc: run the copies in worker processes.
    :raises UsageError: a group whose agents cannot share a model, or a centralized critic without ``state()``.
    """
    centralized = options.critic == "centralized"
    try:
        team = Team([env_fn] * n_envs, monitor_path(monitor_dir), subproc=subproc, with_state=centralized)
    except (AttributeError, NotImplementedError) as exc:
        if not centralized:
            raise
        raise UsageError(f"critic: centralized needs the env's global state(), which it does not provide ({exc})"
                         ) from None
    groups = team_groups(options, team.possible_agents)
    joint = JointStepper(team, groups)
    views: dict[str, GroupVecEnv] = {}
    try:
        for name, agents in groups.items():
            layout = ObsLayout(agents, team.observation_spaces, options.agent_id, team.state_space)
            views[name] = GroupVecEnv(joint, name, layout)
    except UsageError:
        team.close()
        raise
    if seed is not None:
        joint.seed(seed)
    return views


def describe_groups(groups: dict[str, list[str]]) -> str:
    """``adversary: adversary_0, adversary_1; agent: agent_0`` (for logs and errors)."""
    return "; ".join(f"{g}: {', '.join(a)}" for g, a in groups.items())
