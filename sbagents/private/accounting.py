"""Privacy accounting of DP-SGD in an off-policy learner: what was drawn from the replay buffer, and at what cost.

Each gradient step draws one Poisson batch (sample rate ``q``) and takes ``k`` noisy steps on it (DDPG and SAC: the
critic and the actor, k = 2; TD3: k = 1 or 2 with its policy delay). Each step clips every transition's gradient to
``C`` and adds N(0, (sigma C)^2) noise to the sum. The ``k`` releases on one batch together form a Gaussian mechanism
of sensitivity ``sqrt(k) C`` (adaptive composition of Gaussian mechanisms is exactly Gaussian), so the draw is
accounted as one subsampled Gaussian mechanism with noise multiplier ``sigma / sqrt(k)`` and sample rate ``q``, by
Opacus's RDP accountant. Sample rates are rounded *up* to a logarithmic grid (100 steps a decade: at most 2.3%
higher), so the ledger stays small over millions of draws and the epsilon it reports is an upper bound.

The unit of privacy is one transition ``(s, a, r, s', done)`` of the replay buffer.

On-policy learners (PPO, A2C: :class:`RolloutLedger`) train each rollout of ``N = n_steps * n_envs`` transitions for
``n_epochs`` passes of ``ceil(N / batch_size)`` Poisson minibatches (rate ``q = batch_size / N``), one noisy step each,
and then never read it again. Rollouts hold disjoint transitions, so one transition is exposed only to the steps of
its own rollout (parallel composition; later rollouts depend on it only through the private networks, i.e. by
post-processing): the epsilon reported is that of the worst rollout. The composition over every noisy step of
training, the bound that does not rely on rollouts being disjoint, is kept beside it (``epsilon_all_steps``).
"""

from __future__ import annotations

import math
import warnings
from collections import Counter
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from opacus.accountants.analysis.rdp import compute_rdp, get_privacy_spent

#: Sample rates are rounded up to 10 ** (j / GRID) (GRID = 100: steps of 2.3%).
GRID = 100
#: RDP orders: a spread of Opacus's default range (1.1-63) from 2 up. The optimal order for epsilon is about
#: 1 + log(1/delta) / epsilon, so orders below 2 matter only for epsilon above ~11 (where this bound is a little
#: looser); fractional orders below 2 cost ~10x the time of all others together. Any set of orders is a valid bound.
ORDERS: list[float] = [2.0, 2.25, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0, 7.0, 8.0, 10.0, 12.0, 14.0, 16.0, 20.0, 24.0, 28.0,
                       32.0, 40.0, 48.0, 56.0, 64.0]


def round_rate_up(q: float) -> float:
    """``q`` rounded up to the accounting grid (never down; 1 stays 1)."""
    if q >= 1.0:
        return 1.0
    return min(1.0, 10 ** (math.ceil(round(math.log10(q) * GRID, 9)) / GRID))


@lru_cache(maxsize=4096)
def _rdp_of_one_draw(q: float, sigma: float) -> np.ndarray:
    """RDP at :data:`ORDERS` of one subsampled Gaussian draw (cached: a run repeats few ``(q, sigma)``)."""
    return np.asarray(compute_rdp(q=q, noise_multiplier=sigma, steps=1, orders=ORDERS))


def epsilon_of(draws: Counter[tuple[float, int]], noise_multiplier: float, delta: float) -> float:
    """Epsilon after ``draws`` (``{(q, k): count}``) with noise multiplier ``sigma`` per step, at ``delta``."""
    if not draws:
        return 0.0
    if noise_multiplier <= 0:
        return math.inf
    rdp = sum(n * _rdp_of_one_draw(q, noise_multiplier / math.sqrt(k)) for (q, k), n in draws.items())
    with warnings.catch_warnings():  # "optimal order is the smallest alpha": epsilon above ~11, see ORDERS
        warnings.simplefilter("ignore", UserWarning)
        # opacus annotates rdp as list[float] | float; it takes any array (np.atleast_1d), as its docstring says
        eps, _ = get_privacy_spent(orders=ORDERS, rdp=rdp, delta=delta)  # type: ignore[arg-type]
    return float(eps)


def noise_for_epsilon(draws: Counter[tuple[float, int]], epsilon: float, delta: float, tol: float = 0.005) -> float:
    """The smallest noise multiplier (to a relative ``tol`` in epsilon) that keeps ``draws`` within
    ``(epsilon, delta)``: a bracket, then false position on log(epsilon) against log(sigma). When even the
    smallest noise tried (~1e-3) keeps ``epsilon`` (no draws at all, or very few), that noise.

    :raises ValueError: ``epsilon`` <= 0, or no noise below 1e4 is enough.
    """
    if epsilon <= 0:
        raise ValueError(f"epsilon must be > 0, got {epsilon}")

    def gap(sigma: float) -> float:  # log(eps(sigma) / epsilon): decreasing in sigma
        return math.log(max(epsilon_of(draws, sigma, delta), 1e-300) / epsilon)

    lo, hi = 0.5, 1.0
    g_lo, g_hi = gap(lo), gap(hi)
    while g_hi > 0:
        lo, g_lo, hi = hi, g_hi, hi * 4
        if hi > 1e4:
            raise ValueError(f"no noise multiplier below 1e4 reaches epsilon {epsilon} at delta {delta}")
        g_hi = gap(hi)
    while g_lo <= 0 and lo > 1e-3:
        hi, g_hi, lo = lo, g_lo, lo / 4
        g_lo = gap(lo)
    if g_lo <= 0:  # even ~1e-3 noise keeps epsilon (e.g. a budget too small for one gradient step): no bracket
        return lo
    for _ in range(60):
        if -tol <= g_hi <= 0:
            break
        w = g_lo / (g_lo - g_hi)  # false position in log-log coordinates
        mid = math.exp(math.log(lo) + min(max(w, 0.02), 0.98) * (math.log(hi) - math.log(lo)))
        g_mid = gap(mid)
        lo, g_lo, hi, g_hi = (mid, g_mid, hi, g_hi) if g_mid > 0 else (lo, g_lo, mid, g_mid)
    return hi


@dataclass
class PrivacyLedger:
    """The draws and noisy steps of one training run, and the epsilon they spend.

    :param noise_multiplier: sigma of every noisy step (noise std / clipping norm).
    :param delta: the delta epsilon is reported at.
    """

    noise_multiplier: float
    delta: float

    def __post_init__(self) -> None:
        self.draws: Counter[tuple[float, int]] = Counter()
        self._pending_q: float | None = None
        self._pending_k = 0
        self.n_draws = 0
        self.n_steps = 0

    def on_draw(self, q: float) -> None:
        """A new batch was drawn with sample rate ``q`` (commits the previous draw)."""
        self._commit()
        self._pending_q = round_rate_up(q)
        self.n_draws += 1

    def on_step(self) -> None:
        """A noisy optimizer step was taken on the current batch."""
        if self._pending_q is None:
            raise RuntimeError("a DP step before any Poisson draw: the model's replay buffer is not a "
                               "PoissonReplayBuffer wired to this ledger")
        self._pending_k += 1
        self.n_steps += 1

    def spent(self) -> Counter[tuple[float, int]]:
        """Every draw so far, the current one included, as ``{(q, k): count}``."""
        out = Counter(self.draws)
        if self._pending_q is not None and self._pending_k:
            out[(self._pending_q, self._pending_k)] += 1
        return out

    def epsilon(self) -> float:
        """Epsilon spent so far at :attr:`delta`."""
        return epsilon_of(self.spent(), self.noise_multiplier, self.delta)

    def _commit(self) -> None:
        if self._pending_q is not None and self._pending_k:
            self.draws[(self._pending_q, self._pending_k)] += 1
        self._pending_q, self._pending_k = None, 0


class RolloutLedger(PrivacyLedger):
    """:class:`PrivacyLedger` of an on-policy learner: draws grouped by rollout (see the module docstring).

    :meth:`epsilon` is the worst rollout's (parallel composition over disjoint rollouts); :meth:`epsilon_all_steps`
    composes every noisy step of training.
    """

    def __post_init__(self) -> None:
        super().__post_init__()
        self._rollout_start: Counter[tuple[float, int]] = Counter()
        #: the distinct per-rollout schedules of the finished rollouts, as sorted ``((q, k), count)`` tuples
        self.rollout_schedules: set[tuple[tuple[tuple[float, int], int], ...]] = set()
        self.n_rollouts = 0

    def on_rollout(self) -> None:
        """A new rollout begins (new transitions): the draws of the previous one are closed."""
        self._commit()
        self._close_rollout()
        self.n_rollouts += 1

    def current_rollout(self) -> Counter[tuple[float, int]]:
        """The draws on the current rollout's transitions, as ``{(q, k): count}``."""
        return self.spent() - self._rollout_start

    def epsilon(self) -> float:
        """Epsilon spent on any one transition so far: the worst rollout's."""
        schedules = [*self.rollout_schedules, _as_key(self.current_rollout())]
        return max(_epsilon_of_key(s, self.noise_multiplier, self.delta) for s in schedules)

    def epsilon_all_steps(self) -> float:
        """Epsilon of every noisy step of training composed (an upper bound of :meth:`epsilon`)."""
        return epsilon_of(self.spent(), self.noise_multiplier, self.delta)

    def _close_rollout(self) -> None:
        current = self.current_rollout()
        if current:
            self.rollout_schedules.add(_as_key(current))
        self._rollout_start = self.spent()


def _as_key(draws: Counter[tuple[float, int]]) -> tuple[tuple[tuple[float, int], int], ...]:
    """``draws`` as a hashable, sorted tuple."""
    return tuple(sorted(draws.items()))


@lru_cache(maxsize=256)
def _epsilon_of_key(key: tuple[tuple[tuple[float, int], int], ...], noise_multiplier: float, delta: float) -> float:
    """:func:`epsilon_of` of a schedule given by :func:`_as_key` (cached: a run has one or two schedules)."""
    return epsilon_of(Counter(dict(key)), noise_multiplier, delta)


def rollout_schedule(n_transitions: int, batch_size: int | None, n_epochs: int) -> Counter[tuple[float, int]]:
    """The draws on one rollout of ``n_transitions``: ``n_epochs`` passes of ``ceil(N / batch_size)`` Poisson
    minibatches at ``q = batch_size / N`` (``batch_size`` None: one full batch a pass, ``q = 1``), one noisy step
    each, as ``{(q, 1): count}``."""
    if batch_size is None or batch_size >= n_transitions:
        return Counter({(1.0, 1): n_epochs * (1 if batch_size is None else math.ceil(n_transitions / batch_size))})
    q = round_rate_up(batch_size / n_transitions)
    return Counter({(q, 1): n_epochs * math.ceil(n_transitions / batch_size)})


def planned_rollouts(total_timesteps: int, n_transitions: int) -> int:
    """The rollouts SB3's on-policy ``learn(total_timesteps)`` trains on: full rollouts until ``total_timesteps``."""
    return math.ceil(max(total_timesteps, 0) / n_transitions)


def planned_draws(total_timesteps: int, n_envs: int, batch_size: int, learning_starts: int, train_freq: int,
                  gradient_steps: int, buffer_size: int, steps_per_draw: tuple[int, ...]) -> Counter[tuple[float, int]]:
    """The draws an SB3 off-policy ``learn(total_timesteps)`` will make, as ``{(q, k): count}`` (for calibrating the
    noise to a target epsilon before training).

    Follows SB3's loop: ``train_freq`` vec steps (``n_envs`` transitions each) per rollout, then, once
    ``num_timesteps > learning_starts``, ``gradient_steps`` draws (-1: as many as transitions collected, as SB3
    does) on a buffer of ``min(num_timesteps, buffer_size)`` transitions. ``steps_per_draw`` is the cycle of noisy
    steps per draw (``(2,)`` for DDPG and SAC; TD3 with policy delay 2: ``(1, 2)``, as SB3 counts updates from 1).
    """
    draws: Counter[tuple[float, int]] = Counter()
    capacity = max(buffer_size // n_envs, 1) * n_envs
    num_timesteps, n_updates = 0, 0
    while num_timesteps < total_timesteps:
        num_timesteps += train_freq * n_envs
        if num_timesteps <= learning_starts:
            continue
        q = round_rate_up(min(1.0, batch_size / min(num_timesteps, capacity)))
        for _ in range(gradient_steps if gradient_steps >= 0 else train_freq * n_envs):
            draws[(q, steps_per_draw[n_updates % len(steps_per_draw)])] += 1
            n_updates += 1
    return draws
