"""The algorithm table: every name the CLIs accept, with the spaces each algorithm can handle, and the capability
table built from it and from what each feature declares it supports (``train --list`` and the docs table).

A feature declares its algorithms itself, as :class:`~sbagents.capabilities.Capability` objects, found through the
sources named in :data:`sbagents.registration.CAPABILITY_SOURCES` (every registered training extension's
:meth:`~sbagents.extensions.TrainingExtension.capabilities`, federated homes, the team kind's centralized critic, the
backends), imported by path when the table or :func:`algos_with` needs them, so that this module imports none of them.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator
from dataclasses import dataclass

from gymnasium import spaces
from sb3_contrib import ARS, QRDQN, TQC, TRPO, CrossQ, MaskablePPO, RecurrentPPO
from stable_baselines3 import A2C, DDPG, DQN, PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm

from sbagents.algos.pqn import PQN
from sbagents.algos.tabular import SARSA, QLearning
from sbagents.capabilities import Capability
from sbagents.registration import CAPABILITY_SOURCES

_ANY_ACTION = (spaces.Box, spaces.Discrete, spaces.MultiDiscrete, spaces.MultiBinary)
_ANY_OBS = (spaces.Box, spaces.Discrete, spaces.MultiDiscrete, spaces.MultiBinary, spaces.Dict)


@dataclass(frozen=True)
class AlgoSpec:
    """One trainable algorithm.

    :param cls: the SB3-compatible algorithm class.
    :param action_spaces: action space types it can act in.
    :param observation_spaces: observation space types it can read.
    :param off_policy: True for replay-buffer algorithms (they accept ``replay_buffer_class``, e.g. HER).
    :param masked: acts with action masks (the env must have ``action_masks()``: turn-based games).
    :param recurrent: its policy keeps a hidden state between steps (sb3-contrib's ``RecurrentPPO``): it acts
        through ``predict(obs, state, episode_start)`` and trains on sequences from its own rollout buffer.
    """

    cls: type[BaseAlgorithm]
    action_spaces: tuple[type[spaces.Space], ...]
    observation_spaces: tuple[type[spaces.Space], ...] = _ANY_OBS
    off_policy: bool = False
    masked: bool = False
    recurrent: bool = False

    def supports(self, observation_space: spaces.Space, action_space: spaces.Space) -> bool:
        """Whether this algorithm can learn in an env with these spaces."""
        return isinstance(action_space, self.action_spaces) and isinstance(
            observation_space, self.observation_spaces
        )


ALGOS: dict[str, AlgoSpec] = {
    "a2c": AlgoSpec(A2C, _ANY_ACTION),
    "ppo": AlgoSpec(PPO, _ANY_ACTION),
    "ppo_lstm": AlgoSpec(RecurrentPPO, _ANY_ACTION, recurrent=True),  # RL Zoo's name for sb3-contrib's RecurrentPPO
    "trpo": AlgoSpec(TRPO, _ANY_ACTION),
    "ppo_mask": AlgoSpec(MaskablePPO, (spaces.Discrete, spaces.MultiDiscrete, spaces.MultiBinary), masked=True),
    "ars": AlgoSpec(ARS, (spaces.Box, spaces.Discrete), (spaces.Box, spaces.Discrete)),
    "dqn": AlgoSpec(DQN, (spaces.Discrete,), off_policy=True),
    "qrdqn": AlgoSpec(QRDQN, (spaces.Discrete,), off_policy=True),
    "pqn": AlgoSpec(PQN, (spaces.Discrete,), (spaces.Box, spaces.Discrete)),  # parallel Q-learning, no replay buffer
    "ddpg": AlgoSpec(DDPG, (spaces.Box,), off_policy=True),
    "td3": AlgoSpec(TD3, (spaces.Box,), off_policy=True),
    "sac": AlgoSpec(SAC, (spaces.Box,), off_policy=True),
    "tqc": AlgoSpec(TQC, (spaces.Box,), off_policy=True),
    "crossq": AlgoSpec(CrossQ, (spaces.Box,), off_policy=True),
    "qlearning": AlgoSpec(QLearning, (spaces.Discrete,), (spaces.Discrete,)),
    "sarsa": AlgoSpec(SARSA, (spaces.Discrete,), (spaces.Discrete,)),
}


def algos_for(observation_space: spaces.Space, action_space: spaces.Space, masks: bool = False) -> list[str]:
    """Names of the algorithms that can learn in an env with these spaces.

    :param masks: the env has action masks (turn-based games): only the masked algorithms fit; without masks
        they do not.
    """
    return [name for name, spec in ALGOS.items()
            if spec.supports(observation_space, action_space) and spec.masked == masks]


#: The columns of :func:`capability_rows` before the capabilities'.
_ROW_KEYS = ("algo", "actions", "observations", "kind")


def _declared() -> Iterator[Capability]:
    """Every declared capability, in column order: those of each source of
    :data:`~sbagents.registration.CAPABILITY_SOURCES` (the registered extensions' first; each imported only when
    reached)."""
    for path in CAPABILITY_SOURCES:
        module, _, name = path.partition(":")
        yield from getattr(importlib.import_module(module), name)()


def declared_capabilities() -> list[Capability]:
    """Every declared capability with algorithms (the columns of :func:`capability_rows`), in column order.

    :raises ValueError: two capabilities of one name, or one naming an algorithm that is not in :data:`ALGOS`.
    """
    columns: dict[str, Capability] = {}
    for capability in _declared():
        if capability.algos is None:
            continue
        if capability.name in columns or capability.name in _ROW_KEYS:
            raise ValueError(f"two columns of the capability table are called {capability.name!r} (the second: "
                             f"{capability})")
        unknown = [algo for algo in capability.algos if algo not in ALGOS]
        if unknown:
            raise ValueError(f"capability {capability.name!r} names unknown algorithms {', '.join(unknown)}")
        columns[capability.name] = capability
    return list(columns.values())


def algos_with(name: str) -> tuple[str, ...]:
    """The algorithms of the declared capability ``name`` (a column of :func:`capability_rows`), in table order.

    The sources are imported in column order until one declares ``name`` (the centralized critic of an SB3 team run
    imports no backend).

    :raises KeyError: no capability of that name declares algorithms.
    """
    for capability in _declared():
        if capability.name == name and capability.algos is not None:
            return tuple(algo for algo in ALGOS if algo in capability.algos)
    known = ", ".join(capability.name for capability in declared_capabilities())
    raise KeyError(f"unknown capability {name!r}; known: {known}")


def _space_names(types: tuple[type[spaces.Space], ...]) -> str:
    return ", ".join(t.__name__ for t in types)


def capability_rows() -> list[dict[str, str]]:
    """One row per algorithm: its name, spaces, kind and a mark per declared capability (the table of ``train
    --list``; :func:`declared_capabilities` gives the columns)."""
    columns = declared_capabilities()
    rows = []
    for name, spec in ALGOS.items():
        row = {"algo": name, "actions": _space_names(spec.action_spaces),
               "observations": "any" if spec.observation_spaces == _ANY_OBS else _space_names(spec.observation_spaces),
               "kind": "masked" if spec.masked else "off-policy" if spec.off_policy else
               "on-policy, recurrent" if spec.recurrent else "on-policy"}
        row.update({column.name: "yes" if column.algos and name in column.algos else "" for column in columns})
        rows.append(row)
    return rows


def capability_table(markdown: bool = False) -> str:
    """:func:`capability_rows` as an aligned text table, or as a Markdown table (``docs/architecture.md``)."""
    rows = capability_rows()
    header = list(rows[0])
    if markdown:
        lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        return "\n".join(lines + ["| " + " | ".join(row.values()) + " |" for row in rows])
    widths = {key: max(len(key), *(len(row[key]) for row in rows)) for key in header}
    lines = ["  ".join(key.ljust(widths[key]) for key in header)]
    lines += ["  ".join(row[key].ljust(widths[key]) for key in header) for row in rows]
    return "\n".join(line.rstrip() for line in lines)


def capability_legend() -> list[str]:
    """One line per column of :func:`capability_rows`: its name, what it is and the env kinds it takes."""
    lines = []
    for column in declared_capabilities():
        kinds = f"; {' and '.join(column.kinds)} envs" if column.kinds is not None else ""
        lines.append(f"{column.name}: {column.description}{kinds}")
    return lines


__all__ = ["ALGOS", "AlgoSpec", "QLearning", "SARSA", "algos_for", "algos_with", "capability_legend",
           "capability_rows", "capability_table", "declared_capabilities"]
