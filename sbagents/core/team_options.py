"""How the agents of a PettingZoo env map to SB3 models: the multi-agent keys of a zoo entry."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from sbagents.capabilities import Capability
from sbagents.core.env_kinds import TEAM
from sbagents.errors import UsageError

if TYPE_CHECKING:
    from sbagents.core.experiment import Experiment

POLICY_MODES = ("shared", "per_agent", "per_group")
CRITICS = ("local", "centralized")
#: ``critic: centralized``: the algorithms with a value function to centralize (the capability table's
#: ``centralized_critic`` column; :data:`sbagents.registration.CAPABILITY_SOURCES` names :func:`capabilities`).
CENTRALIZED_CRITIC = Capability("centralized_critic", "critic: centralized (PettingZoo teams)", ("a2c", "ppo"),
                                (TEAM.name,), label="critic: centralized")


def capabilities() -> list[Capability]:
    """What the team settings declare for the capability table: :data:`CENTRALIZED_CRITIC`."""
    return [CENTRALIZED_CRITIC]


@dataclass
class TeamOptions:
    """How the agents of a PettingZoo env map to SB3 models (the multi-agent keys of a zoo entry).

    :param policies: ``shared`` (one model for every agent: parameter sharing), ``per_agent`` (a model per agent)
        or ``per_group`` (a model per group: agents named ``<group>_<k>``, or :attr:`groups`).
    :param groups: an explicit group -> agents mapping for ``per_group`` (None: by name prefix).
    :param agent_id: append a one-hot agent id to each agent's observation (useful with ``shared``).
    :param critic: ``local`` (the value function sees the agent's observation) or ``centralized`` (it sees the env's
        global ``state()`` plus the agent id; PPO; actors still act on their own observations).
    """

    policies: str = "shared"
    groups: dict[str, list[str]] | None = None
    agent_id: bool = False
    critic: str = "local"

    @classmethod
    def of(cls, exp: Experiment) -> TeamOptions:
        """The team settings of ``exp`` (its :attr:`~sbagents.core.experiment.Experiment.kind_options`).

        :raises TypeError: the experiment of another env kind (a caller's bug, not the user's).
        """
        if not isinstance(exp.kind_options, cls):
            raise TypeError(f"{exp.env_id} is not a team's experiment (its kind options are "
                            f"{type(exp.kind_options).__name__})")
        return exp.kind_options


def team_options(entry: Mapping[str, Any], source: str) -> TeamOptions:
    """The team settings of a PettingZoo entry (``policies``, ``groups``, ``agent_id``, ``critic``), checked.

    :raises UsageError: (one line naming ``source``) a value out of range.
    """
    policies = entry.get("policies", "shared")
    if policies not in POLICY_MODES:
        raise UsageError(f"policies must be one of {', '.join(POLICY_MODES)}, got {policies!r} ({source})")
    critic = entry.get("critic", "local")
    if critic not in CRITICS:
        raise UsageError(f"critic must be one of {', '.join(CRITICS)}, got {critic!r} ({source})")
    groups = entry.get("groups")
    if groups is not None:
        if not isinstance(groups, dict) or not all(isinstance(v, list) and v for v in groups.values()):
            raise UsageError(f"groups must map group names to lists of agents, got {groups!r} ({source})")
        if policies != "per_group":
            raise UsageError(f"groups needs policies: per_group, got policies: {policies} ({source})")
        groups = {str(k): [str(a) for a in v] for k, v in groups.items()}
    agent_id = entry.get("agent_id", False)
    if not isinstance(agent_id, bool):
        raise UsageError(f"agent_id must be true or false, got {agent_id!r} ({source})")
    return TeamOptions(policies, groups, agent_id, critic)
