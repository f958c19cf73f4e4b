"""A rollout buffer that also holds per-step costs, their value estimates, GAE advantages and returns."""

from __future__ import annotations

from collections.abc import Generator
from typing import NamedTuple

import numpy as np
import torch as th
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.vec_env import VecNormalize


class CostRolloutBufferSamples(NamedTuple):
    """SB3's ``RolloutBufferSamples`` plus the cost fields; every tensor has shape ``(batch,)`` except
    ``observations`` ``(batch, *obs_shape)`` and ``actions`` ``(batch, action_dim)``."""

    observations: th.Tensor
    actions: th.Tensor
    old_values: th.Tensor
    old_log_prob: th.Tensor
    advantages: th.Tensor
    returns: th.Tensor
    old_cost_values: th.Tensor
    cost_advantages: th.Tensor
    cost_returns: th.Tensor


class CostRolloutBuffer(RolloutBuffer):
    """:class:`~stable_baselines3.common.buffers.RolloutBuffer` with ``costs``, ``cost_values``,
    ``cost_advantages`` and ``cost_returns``, all of shape ``(buffer_size, n_envs)`` until :meth:`get` flattens
    them to ``(buffer_size * n_envs,)`` like the reward arrays.

    SB3's ``add`` does not see the costs: the algorithm writes ``costs`` and ``cost_values`` after the rollout
    and calls :meth:`compute_cost_returns_and_advantage`.

    :param cost_gamma: discount of the cost returns (default: ``gamma``).
    :param cost_gae_lambda: GAE lambda of the cost advantages (default: ``gae_lambda``).
    Other parameters as :class:`~stable_baselines3.common.buffers.RolloutBuffer`.
    """

    costs: np.ndarray
    cost_values: np.ndarray
    cost_advantages: np.ndarray
    cost_returns: np.ndarray
    reward_advantages: np.ndarray

    def __init__(
        self,
        *args: object,
        cost_gamma: float | None = None,
        cost_gae_lambda: float | None = None,
        **kwargs: object,
    ) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self.cost_gamma = self.gamma if cost_gamma is None else float(cost_gamma)
        self.cost_gae_lambda = self.gae_lambda if cost_gae_lambda is None else float(cost_gae_lambda)

    def reset(self) -> None:
        shape = (self.buffer_size, self.n_envs)
        self.costs = np.zeros(shape, dtype=np.float32)
        self.cost_values = np.zeros(shape, dtype=np.float32)
        self.cost_advantages = np.zeros(shape, dtype=np.float32)
        self.cost_returns = np.zeros(shape, dtype=np.float32)
        self.reward_advantages = np.zeros(shape, dtype=np.float32)
        super().reset()

    def compute_cost_returns_and_advantage(self, last_cost_values: np.ndarray, dones: np.ndarray) -> None:
        """GAE(``cost_gae_lambda``) of the costs and their TD(lambda) returns, exactly as SB3 does for rewards.

        Call it before :meth:`get`, with ``costs`` and ``cost_values`` filled (a time-limit truncation's
        bootstrap ``cost_gamma * V_c(terminal_obs)`` already added to its step's cost).

        :param last_cost_values: ``V_c`` of the observation after the last step, shape ``(n_envs,)``.
        :param dones: whether the last step ended an episode, shape ``(n_envs,)``.
        """
        last_values = np.asarray(last_cost_values, dtype=np.float32).reshape(self.n_envs)
        last_gae_lam = np.zeros(self.n_envs, dtype=np.float32)
        for step in reversed(range(self.buffer_size)):
            if step == self.buffer_size - 1:
                next_non_terminal = 1.0 - np.asarray(dones, dtype=np.float32)
                next_values = last_values
            else:
                next_non_terminal = 1.0 - self.episode_starts[step + 1]
                next_values = self.cost_values[step + 1]
            delta = self.costs[step] + self.cost_gamma * next_values * next_non_terminal - self.cost_values[step]
            last_gae_lam = delta + self.cost_gamma * self.cost_gae_lambda * next_non_terminal * last_gae_lam
            self.cost_advantages[step] = last_gae_lam
        self.cost_returns = self.cost_advantages + self.cost_values

    def get(self, batch_size: int | None = None) -> Generator[CostRolloutBufferSamples, None, None]:  # type: ignore[override]
        if not self.generator_ready:
            for name in ("costs", "cost_values", "cost_advantages", "cost_returns", "reward_advantages"):
                self.__dict__[name] = self.swap_and_flatten(self.__dict__[name])
        yield from super().get(batch_size)  # type: ignore[misc]

    def _get_samples(  # type: ignore[override]
        self, batch_inds: np.ndarray, env: VecNormalize | None = None
    ) -> CostRolloutBufferSamples:
        base = super()._get_samples(batch_inds, env)
        extra = (self.cost_values[batch_inds], self.cost_advantages[batch_inds], self.cost_returns[batch_inds])
        return CostRolloutBufferSamples(*base, *(self.to_torch(a.flatten()) for a in extra))
