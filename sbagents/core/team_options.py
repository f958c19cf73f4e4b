"""How the agents of a PettingZoo env map to SB3 models: the multi-agent keys of a zoo entry."""

from __future__ import annotations

from dataclasses import dataclass

POLICY_MODES = ("shared", "per_agent", "per_group")
CRITICS = ("local", "centralized")


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
