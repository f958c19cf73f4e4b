"""A replay buffer whose batches are Poisson samples: the sampling that DP-SGD's privacy accounting assumes.

SB3's :class:`~stable_baselines3.common.buffers.ReplayBuffer` draws a fixed number of transitions with replacement;
the subsampled-Gaussian analysis behind the RDP accountant is for Poisson sampling, where every stored transition
joins a batch independently with probability ``q``. :class:`PoissonReplayBuffer` does that, with
``q = min(1, batch_size / N)`` for ``N`` stored transitions (``N`` counts transitions: positions x env copies), so a
batch holds ``batch_size`` transitions on average. Each draw's ``q`` is handed to a listener (the privacy ledger).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

#: Redraws of an empty Poisson batch before giving up (an empty batch has probability (1 - q) ** N).
MAX_REDRAWS = 100


class PoissonReplayBuffer(ReplayBuffer):
    """:class:`~stable_baselines3.common.buffers.ReplayBuffer` with Poisson-sampled batches.

    Use it as ``replay_buffer_class`` of DDPG, TD3 or SAC. ``optimize_memory_usage`` is not supported (its last
    position holds no valid transition). An empty draw is redrawn: its probability is ``(1 - q) ** N``, e.g.
    ``exp(-batch_size)``, so this changes nothing measurable for batches of tens of transitions.
    """

    def __init__(self, *args: object, **kwargs: object) -> None:
        if kwargs.get("optimize_memory_usage"):
            raise ValueError("PoissonReplayBuffer does not support optimize_memory_usage=True")
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        #: called with the sample rate of every draw
        self.on_draw: Callable[[float], None] | None = None
        self.n_draws = 0

    def n_transitions(self) -> int:
        """Stored transitions ``N`` (positions x env copies)."""
        return self.size() * self.n_envs

    def sample_rate(self, batch_size: int) -> float:
        """``q = min(1, batch_size / N)``: each stored transition's chance to join a batch."""
        return min(1.0, batch_size / max(self.n_transitions(), 1))

    def sample(self, batch_size: int, env: VecNormalize | None = None) -> ReplayBufferSamples:
        """A Poisson batch: each stored transition independently with probability :meth:`sample_rate`.

        :return: samples of ``batch_size`` transitions on average (shapes ``(n, ...)`` with a random ``n``).
        """
        q = self.sample_rate(batch_size)
        for _ in range(MAX_REDRAWS):
            chosen = np.random.random((self.size(), self.n_envs)) < q
            if chosen.any():
                break
        else:
            raise RuntimeError(f"{MAX_REDRAWS} empty Poisson batches in a row (q = {q:.3g}, "
                               f"N = {self.n_transitions()})")
        self.n_draws += 1
        if self.on_draw is not None:
            self.on_draw(q)
        positions, env_indices = np.nonzero(chosen)
        return self._transitions(positions, env_indices, env)

    def _transitions(self, positions: np.ndarray, env_indices: np.ndarray,
                     env: VecNormalize | None) -> ReplayBufferSamples:
        """The transitions at ``(positions[i], env_indices[i])``, as SB3's ``_get_samples`` builds them."""
        dones = self.dones[positions, env_indices] * (1 - self.timeouts[positions, env_indices])
        data = (
            self._normalize_obs(self.observations[positions, env_indices, :], env),
            self.actions[positions, env_indices, :],
            self._normalize_obs(self.next_observations[positions, env_indices, :], env),
            dones.reshape(-1, 1),
            self._normalize_reward(self.rewards[positions, env_indices].reshape(-1, 1), env),
        )
        return ReplayBufferSamples(*tuple(map(self.to_torch, data)))
