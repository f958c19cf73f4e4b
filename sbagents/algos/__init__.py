"""The algorithm table: every name the CLIs accept, with the spaces each algorithm can handle and the training
features it supports (the one capability table: refusals, ``train --list`` and the docs table come from it)."""

from __future__ import annotations

from dataclasses import dataclass

from gymnasium import spaces
from sb3_contrib import ARS, QRDQN, TQC, TRPO, CrossQ, MaskablePPO, RecurrentPPO
from stable_baselines3 import A2C, DDPG, DQN, PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm

from sbagents.algos.tabular import SARSA, QLearning

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
    :param features: the training features it supports (:data:`FEATURES`).
    """

    cls: type[BaseAlgorithm]
    action_spaces: tuple[type[spaces.Space], ...]
    observation_spaces: tuple[type[spaces.Space], ...] = _ANY_OBS
    off_policy: bool = False
    masked: bool = False
    recurrent: bool = False
    features: frozenset[str] = frozenset()

    def supports(self, observation_space: spaces.Space, action_space: spaces.Space) -> bool:
        """Whether this algorithm can learn in an env with these spaces."""
        return isinstance(action_space, self.action_spaces) and isinstance(
            observation_space, self.observation_spaces
        )


#: Training features an algorithm may support -> what the feature is (the columns of the capability table).
FEATURES: dict[str, str] = {
    "dp": "DP-SGD training (--dp-*)",
    "robust:sa": "--robust sa (state-adversarial regularizer)",
    "robust:adv": "--robust adv (adversarial rollouts)",
    "robust:sa+adv": "--robust sa+adv",
    "constrained": "--constraint (Lagrangian / PID multiplier)",
    "federated": "federated homes (python -m sbagents.federated)",
    "rllib": "--backend rllib (PettingZoo envs)",
    "centralized_critic": "critic: centralized (PettingZoo teams)",
}


def _features(*names: str) -> frozenset[str]:
    unknown = set(names) - set(FEATURES)
    assert not unknown, unknown
    return frozenset(names)


ALGOS: dict[str, AlgoSpec] = {
    "a2c": AlgoSpec(A2C, _ANY_ACTION, features=_features("dp", "federated", "centralized_critic")),
    "ppo": AlgoSpec(PPO, _ANY_ACTION,
                    features=_features("dp", "constrained", "federated", "rllib", "centralized_critic")),
    "ppo_lstm": AlgoSpec(RecurrentPPO, _ANY_ACTION, recurrent=True),  # RL Zoo's name for sb3-contrib's RecurrentPPO
    "trpo": AlgoSpec(TRPO, _ANY_ACTION),
    "ppo_mask": AlgoSpec(MaskablePPO, (spaces.Discrete, spaces.MultiDiscrete, spaces.MultiBinary), masked=True),
    "ars": AlgoSpec(ARS, (spaces.Box, spaces.Discrete), (spaces.Box, spaces.Discrete)),
    "dqn": AlgoSpec(DQN, (spaces.Discrete,), off_policy=True),
    "qrdqn": AlgoSpec(QRDQN, (spaces.Discrete,), off_policy=True),
    "ddpg": AlgoSpec(DDPG, (spaces.Box,), off_policy=True,
                     features=_features("dp", "robust:sa", "robust:adv", "robust:sa+adv", "federated")),
    "td3": AlgoSpec(TD3, (spaces.Box,), off_policy=True,
                    features=_features("dp", "robust:sa", "robust:adv", "robust:sa+adv", "federated")),
    "sac": AlgoSpec(SAC, (spaces.Box,), off_policy=True,
                    features=_features("dp", "robust:adv", "constrained", "federated")),
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


def algos_with(feature: str) -> tuple[str, ...]:
    """The algorithms that support ``feature`` (a key of :data:`FEATURES`), in table order."""
    if feature not in FEATURES:
        raise KeyError(f"unknown feature {feature!r}; known: {', '.join(FEATURES)}")
    return tuple(name for name, spec in ALGOS.items() if feature in spec.features)


def _space_names(types: tuple[type[spaces.Space], ...]) -> str:
    return ", ".join(t.__name__ for t in types)


def capability_rows() -> list[dict[str, str]]:
    """One row per algorithm: its name, spaces, kind and a mark per feature (the table of ``train --list``)."""
    rows = []
    for name, spec in ALGOS.items():
        row = {"algo": name, "actions": _space_names(spec.action_spaces),
               "observations": "any" if spec.observation_spaces == _ANY_OBS else _space_names(spec.observation_spaces),
               "kind": "masked" if spec.masked else "off-policy" if spec.off_policy else
               "on-policy, recurrent" if spec.recurrent else "on-policy"}
        row.update({feature: "yes" if feature in spec.features else "" for feature in FEATURES})
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


__all__ = ["ALGOS", "FEATURES", "AlgoSpec", "QLearning", "SARSA", "algos_for", "algos_with", "capability_rows",
           "capability_table"]
