"""Death masking for SB3: transitions of absent agents (dead, or not arrived yet) never reach the loss.

A team VecEnv marks the slots whose action was not used with ``info["sbagents_acted"] = False``
(:mod:`sbagents.multiagent.team`). The buffers here keep those transitions out of training:

- :class:`MaskedRolloutBuffer` and :class:`MaskedDictRolloutBuffer` (PPO, A2C; ``rollout_buffer_class``):
  minibatches are drawn from the acted transitions only. :class:`ActedMaskCallback` tells it, before each ``add``,
  which slots acted. An agent's last real step is a done step, so no return or advantage of a real step reaches
  across its absence.
- :class:`MaskedReplayBuffer` (DQN, SAC, TD3, ...; ``replay_buffer_class``): samples only acted transitions.

When every slot acts (no agent ever leaves) both behave exactly like SB3's buffers, random numbers included.
"""

from __future__ import annotations

from collections.abc import Generator
from typing import Any

import numpy as np
from stable_baselines3.common.buffers import DictRolloutBuffer, ReplayBuffer, RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import DictRolloutBufferSamples, ReplayBufferSamples, RolloutBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

from sbagents.core.info_keys import ACTED


def acted_mask(infos: list[dict[str, Any]]) -> np.ndarray:
    """``(n_envs,)`` bool: which slots' actions were used this step."""
    return np.array([info.get(ACTED, True) for info in infos], dtype=bool)


def _acted_minibatches(buffer: RolloutBuffer | DictRolloutBuffer, acted: np.ndarray, batch_size: int | None,
                       observation_keys: list[str] | None) -> Generator[Any, None, None]:
    """SB3's rollout minibatches drawn from the acted transitions only (``observation_keys``: a Dict buffer's)."""
    assert buffer.full, ""
    valid = np.flatnonzero(buffer.swap_and_flatten(acted[..., None]).reshape(-1))
    indices = np.random.permutation(valid)
    if not buffer.generator_ready:
        if observation_keys is None:
            buffer.observations = buffer.swap_and_flatten(buffer.observations)  # type: ignore[arg-type]
        else:
            for key in observation_keys:
                buffer.observations[key] = buffer.swap_and_flatten(buffer.observations[key])  # type: ignore[index]
        for name in ("actions", "values", "log_probs", "advantages", "returns"):
            buffer.__dict__[name] = buffer.swap_and_flatten(buffer.__dict__[name])
        buffer.generator_ready = True
    if batch_size is None:
        batch_size = len(indices)
    for start in range(0, len(indices), max(batch_size, 1)):
        yield buffer._get_samples(indices[start : start + batch_size])


class _ActedRows:
    """Mixin for SB3 rollout buffers: an ``acted`` mask ``(buffer_size, n_envs)`` filled from :attr:`next_acted`."""

    buffer_size: int
    n_envs: int
    pos: int

    def reset(self) -> None:
        super().reset()  # type: ignore[misc]
        self.acted = np.ones((self.buffer_size, self.n_envs), dtype=bool)
        self.next_acted: np.ndarray | None = None

    def add(self, *args: Any, **kwargs: Any) -> None:
        if self.next_acted is not None:
            self.acted[self.pos] = self.next_acted
            self.next_acted = None
        super().add(*args, **kwargs)  # type: ignore[misc]


class MaskedRolloutBuffer(_ActedRows, RolloutBuffer):
    """SB3's ``RolloutBuffer`` that trains on acted transitions only (set :attr:`next_acted` before ``add``)."""

    def get(self, batch_size: int | None = None) -> Generator[RolloutBufferSamples, None, None]:
        yield from _acted_minibatches(self, self.acted, batch_size, None)


class MaskedDictRolloutBuffer(_ActedRows, DictRolloutBuffer):
    """:class:`MaskedRolloutBuffer` for Dict observations (e.g. a centralized critic's ``obs`` and ``state``)."""

    def get(self, batch_size: int | None = None) -> Generator[DictRolloutBufferSamples, None, None]:  # type: ignore[override]
        yield from _acted_minibatches(self, self.acted, batch_size, list(self.observations))


class ActedMaskCallback(BaseCallback):
    """Passes each step's acted slots to the model's :class:`MaskedRolloutBuffer` (on-policy algorithms)."""

    def _on_step(self) -> bool:
        buffer = getattr(self.model, "rollout_buffer", None)
        if isinstance(buffer, MaskedRolloutBuffer | MaskedDictRolloutBuffer):
            buffer.next_acted = acted_mask(self.locals["infos"])
        return True


class MaskedReplayBuffer(ReplayBuffer):
    """SB3's ``ReplayBuffer`` that samples acted transitions only (``optimize_memory_usage`` is not supported)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if self.optimize_memory_usage:
            raise ValueError("MaskedReplayBuffer does not support optimize_memory_usage")
        self.acted = np.ones((self.buffer_size, self.n_envs), dtype=bool)

    def add(self, obs: Any, next_obs: Any, action: np.ndarray, reward: np.ndarray, done: np.ndarray,
            infos: list[dict[str, Any]]) -> None:
        self.acted[self.pos] = acted_mask(infos)
        super().add(obs, next_obs, action, reward, done, infos)

    def sample(self, batch_size: int, env: VecNormalize | None = None) -> ReplayBufferSamples:
        upper = self.buffer_size if self.full else self.pos
        if self.acted[:upper].all():
            return super().sample(batch_size, env)
        valid = np.flatnonzero(self.acted[:upper])
        picks = valid[np.random.randint(0, len(valid), size=batch_size)]
        batch_inds, env_indices = np.divmod(picks, self.n_envs)
        data = (
            self._normalize_obs(self.observations[batch_inds, env_indices, :], env),
            self.actions[batch_inds, env_indices, :],
            self._normalize_obs(self.next_observations[batch_inds, env_indices, :], env),
            (self.dones[batch_inds, env_indices] * (1 - self.timeouts[batch_inds, env_indices])).reshape(-1, 1),
            self._normalize_reward(self.rewards[batch_inds, env_indices].reshape(-1, 1), env),
        )
        return ReplayBufferSamples(*tuple(map(self.to_torch, data)))
