"""The algorithm table: every name the CLIs accept, with the spaces each algorithm can handle."""

from __future__ import annotations

from dataclasses import dataclass

from gymnasium import spaces
from sb3_contrib import ARS, QRDQN, TQC, TRPO, CrossQ, MaskablePPO
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
    """

    cls: type[BaseAlgorithm]
    action_spaces: tuple[type[spaces.Space], ...]
    observation_spaces: tuple[type[spaces.Space], ...] = _ANY_OBS
    off_policy: bool = False
    masked: bool = False

    def supports(self, observation_space: spaces.Space, action_space: spaces.Space) -> bool:
        """Whether this algorithm can learn in an env with these spaces."""
        return isinstance(action_space, self.action_spaces) and isinstance(
            observation_space, self.observation_spaces
        )


ALGOS: dict[str, AlgoSpec] = {
    "a2c": AlgoSpec(A2C, _ANY_ACTION),
    "ppo": AlgoSpec(PPO, _ANY_ACTION),
    "trpo": AlgoSpec(TRPO, _ANY_ACTION),
    "ppo_mask": AlgoSpec(MaskablePPO, (spaces.Discrete, spaces.MultiDiscrete, spaces.MultiBinary), masked=True),
    "ars": AlgoSpec(ARS, (spaces.Box, spaces.Discrete), (spaces.Box, spaces.Discrete)),
    "dqn": AlgoSpec(DQN, (spaces.Discrete,), off_policy=True),
    "qrdqn": AlgoSpec(QRDQN, (spaces.Discrete,), off_policy=True),
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


__all__ = ["ALGOS", "AlgoSpec", "QLearning", "SARSA", "algos_for"]
