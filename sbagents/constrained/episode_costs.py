"""What :class:`~sbagents.constrained.PPOLagrangian` and :class:`~sbagents.constrained.SACLagrangian` share: the
Lagrange (or PID) multiplier, the running cost of every training episode, and the multiplier's update from the
episodes that ended since the last one."""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from sbagents.constrained.lagrangian import MULTIPLIERS, LagrangeMultiplier

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm

    _Base = BaseAlgorithm  # the mixin's host, for type checking only
else:
    _Base = object

#: Attributes of the running episode state, left out of saved models.
EPISODE_STATE = ("_running_ep_cost", "_pending_ep_costs")


class EpisodeCostConstraint(_Base):
    """Mixin for an SB3 algorithm trained under ``E[sum_t cost_t] <= cost_limit`` (``info["cost"]`` per step).

    The host calls :meth:`_init_constraint` in its ``__init__``, :meth:`_add_step_costs` on every env step and
    :meth:`_update_multiplier` where its algorithm updates ``lambda`` (PPO: per rollout; SAC: per ``train`` call).
    """

    CONSTRAINTS: ClassVar[dict[str, type[LagrangeMultiplier]]] = MULTIPLIERS
    multiplier: LagrangeMultiplier
    #: The saved multiplier is rebuilt from its plain description (:data:`sbagents.safe_load.PLAIN_ENTRIES_ATTR`).
    plain_entries: ClassVar[dict[str, Any]] = {}

    def _init_constraint(self, cost_limit: float, constraint: str, multiplier_kwargs: dict[str, Any] | None) -> None:
        """Check ``constraint`` and make its multiplier.

        :raises ValueError: an unknown ``constraint``, or multiplier keywords it rejects.
        """
        if constraint not in self.CONSTRAINTS:
            raise ValueError(f"constraint must be one of {sorted(self.CONSTRAINTS)}, got {constraint!r}")
        self.cost_limit = float(cost_limit)
        self.constraint = constraint
        self.multiplier_kwargs = dict(multiplier_kwargs or {})
        self.multiplier = self.CONSTRAINTS[constraint](self.cost_limit, **self.multiplier_kwargs)
        self.ep_cost_buffer: deque[float] = deque(maxlen=100)
        self._running_ep_cost: np.ndarray | None = None
        self._pending_ep_costs: list[float] = []

    @property
    def lagrange_multiplier(self) -> float:
        """The current multiplier ``lambda``."""
        return self.multiplier.value

    def _add_step_costs(self, dones: np.ndarray, infos: list[dict[str, Any]]) -> np.ndarray:
        """Add one env step's costs ``(n_envs,)`` (returned) to the running episodes; an episode that ended waits
        for the next multiplier update."""
        costs = np.array([float(info.get("cost", 0.0)) for info in infos], dtype=np.float32)
        if self._running_ep_cost is None or len(self._running_ep_cost) != len(costs):
            self._running_ep_cost = np.zeros(len(costs), dtype=np.float64)
        self._running_ep_cost += costs
        for idx in np.flatnonzero(dones):
            ep_cost = float(self._running_ep_cost[idx])
            self._pending_ep_costs.append(ep_cost)
            self.ep_cost_buffer.append(ep_cost)
            self._running_ep_cost[idx] = 0.0
        return costs

    def _update_multiplier(self) -> None:
        """One multiplier step from the mean cost of the episodes that ended since the last (none: unchanged)."""
        if self._pending_ep_costs:
            ep_cost = float(np.mean(self._pending_ep_costs))
            self.multiplier.update(ep_cost, timesteps=self.num_timesteps)
            self._pending_ep_costs = []
            self.logger.record("constraint/ep_cost", ep_cost)
        self.logger.record("constraint/multiplier", self.multiplier.value)
        if self.ep_cost_buffer:
            self.logger.record("rollout/ep_cost_mean", float(np.mean(self.ep_cost_buffer)))


def _saved_multiplier(saved: Any, data: dict[str, Any]) -> LagrangeMultiplier:
    """A constrained model's multiplier from its zip: built from the model's plain settings (``constraint``,
    ``cost_limit``, ``multiplier_kwargs``), then given the saved learned state (:meth:`LagrangeMultiplier.restore`).

    :raises ValueError: settings the multiplier rejects.
    """
    method = data.get("constraint")
    if method not in MULTIPLIERS:
        raise ValueError(f"constraint must be one of {sorted(MULTIPLIERS)}, got {method!r:.40}")
    kwargs = data.get("multiplier_kwargs") or {}
    if not isinstance(kwargs, dict):
        raise ValueError("multiplier_kwargs must be a mapping")
    multiplier = MULTIPLIERS[method](float(data.get("cost_limit", 0.0)), **kwargs)
    multiplier.restore(saved)
    return multiplier


EpisodeCostConstraint.plain_entries = {"multiplier": _saved_multiplier}
