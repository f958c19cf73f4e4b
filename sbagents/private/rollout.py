"""A rollout buffer whose minibatches are Poisson samples: the sampling DP-SGD's privacy accounting assumes, for
SB3's on-policy learners (PPO, A2C).

SB3's :class:`~stable_baselines3.common.buffers.RolloutBuffer` shuffles the rollout into fixed-size minibatches each
epoch (sampling without replacement); the subsampled-Gaussian analysis behind the RDP accountant is for Poisson
sampling. :class:`PoissonRolloutBuffer` draws as many minibatches per pass as SB3 does (``ceil(N / batch_size)`` for
``N = n_steps * n_envs`` transitions), each one a fresh Poisson sample: every transition of the rollout joins it
independently with probability ``q = min(1, batch_size / N)``. ``N`` is the rollout's fixed size, not a count of the
data, so ``q`` does not depend on the data. Each draw's ``q`` goes to a listener (the privacy ledger), and so does
the start of every new rollout (rollouts hold disjoint transitions; the ledger composes within one).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator

import numpy as np
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.type_aliases import RolloutBufferSamples

from sbagents.private.replay import MAX_REDRAWS

#: The arrays SB3 flattens from ``(n_steps, n_envs, ...)`` to ``(n_steps * n_envs, ...)`` before sampling.
FLAT_ARRAYS = ("observations", "actions", "values", "log_probs", "advantages", "returns")


class PoissonRolloutBuffer(RolloutBuffer):
    """:class:`~stable_baselines3.common.buffers.RolloutBuffer` with Poisson-sampled minibatches.

    Use it as ``rollout_buffer_class`` of PPO or A2C. ``get(batch_size)`` yields ``ceil(N / batch_size)``
    minibatches of ``batch_size`` transitions on average (``get(None)``, A2C's full batch: one draw with ``q = 1``,
    the whole rollout). An empty draw is redrawn (probability ``(1 - q) ** N``, about ``exp(-batch_size)``).
    """

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        #: called with the sample rate of every draw
        self.on_draw: Callable[[float], None] | None = None
        #: called when the buffer is emptied for a new rollout
        self.on_rollout: Callable[[], None] | None = None
        self.n_draws = 0

    def reset(self) -> None:
        """Empty the buffer for a new rollout (and tell the listener: a new set of transitions)."""
        super().reset()
        listener = getattr(self, "on_rollout", None)  # reset() runs in RolloutBuffer.__init__ too
        if listener is not None:
            listener()

    def n_transitions(self) -> int:
        """Transitions in a full rollout, ``N = n_steps * n_envs``."""
        return self.buffer_size * self.n_envs

    def sample_rate(self, batch_size: int | None) -> float:
        """``q = min(1, batch_size / N)`` (1 for ``None``: the whole rollout)."""
        if batch_size is None:
            return 1.0
        return min(1.0, batch_size / self.n_transitions())

    def draws_per_pass(self, batch_size: int | None) -> int:
        """Minibatches per ``get``: ``ceil(N / batch_size)``, as many as SB3's shuffled pass (1 for ``None``)."""
        return 1 if batch_size is None else math.ceil(self.n_transitions() / batch_size)

    def get(self, batch_size: int | None = None) -> Generator[RolloutBufferSamples, None, None]:
        """One pass (an epoch): :meth:`draws_per_pass` Poisson minibatches of the rollout.

        :return: samples of ``batch_size`` transitions on average (shapes ``(n, ...)`` with a random ``n``).
        """
        assert self.full, "the rollout is not complete"
        if not self.generator_ready:
            for name in FLAT_ARRAYS:
                self.__dict__[name] = self.swap_and_flatten(self.__dict__[name])
            self.generator_ready = True
        q = self.sample_rate(batch_size)
        for _ in range(self.draws_per_pass(batch_size)):
            yield self._get_samples(self._draw(q))

    def _draw(self, q: float) -> np.ndarray:
        """The indices of one Poisson sample with rate ``q`` (reported to :attr:`on_draw`)."""
        n = self.n_transitions()
        for _ in range(MAX_REDRAWS):
            chosen = np.flatnonzero(np.random.random(n) < q)
            if len(chosen):
                break
        else:
            raise RuntimeError(f"{MAX_REDRAWS} empty Poisson batches in a row (q = {q:.3g}, N = {n})")
        self.n_draws += 1
        if self.on_draw is not None:
            self.on_draw(q)
        return chosen
