""":class:`DPCallback`: the privacy spent, logged as training goes, and a stop before the budget would be passed."""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

from sbagents.private.accounting import RolloutLedger
from sbagents.private.dp_sgd import PrivateTraining, planned_epsilon

#: Env steps between ``dp/epsilon`` log entries (TensorBoard, SB3's logger).
LOG_EVERY = 1000


class DPCallback(BaseCallback):
    """Logs ``dp/epsilon`` every ``log_every`` env steps and stops ``learn`` before the draws would spend more than
    ``stop_at`` (for a noise given directly; a noise calibrated to the budget never reaches it). On-policy, every
    rollout spends the same epsilon: a noise that passes the budget in one rollout stops before the first update.

    :param dp: the state :func:`~sbagents.private.dp_sgd.make_private` returned.
    :param stop_at: the epsilon budget (None: never stop).
    :param total_timesteps: the ``learn`` budget, to plan where the privacy budget runs out.
    """

    def __init__(self, dp: PrivateTraining, stop_at: float | None = None, total_timesteps: int | None = None,
                 log_every: int = LOG_EVERY) -> None:
        super().__init__(verbose=0)
        self.dp, self.stop_at, self.total_timesteps, self.log_every = dp, stop_at, total_timesteps, log_every
        self.stop_step: int | None = None
        self.stopped_at_budget = False
        self._next_log = 0

    def _on_training_start(self) -> None:
        if self.stop_at is None or self.total_timesteps is None:
            return
        ledger = self.dp.ledger
        if planned_epsilon(self.model, self.total_timesteps, ledger.noise_multiplier, ledger.delta) > self.stop_at:
            self.stop_step = last_step_within(self.model, self.total_timesteps, self.dp, self.stop_at)

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next_log:
            self.logger.record("dp/epsilon", self.dp.ledger.epsilon())
            if isinstance(self.dp.ledger, RolloutLedger):
                self.logger.record("dp/epsilon_all_steps", self.dp.ledger.epsilon_all_steps())
            self._next_log = self.num_timesteps + self.log_every
        if self.stop_step is not None and self.num_timesteps >= self.stop_step:
            self.stopped_at_budget = True
            return False  # before the next gradient steps: they would pass the budget
        return True

    def summary_items(self) -> dict[str, Any]:
        """``{"dp": ...}`` for ``summary.json``: the privacy spent and how it was accounted."""
        return {"dp": {**self.dp.summary(), "stopped_at_budget": self.stopped_at_budget}}


def last_step_within(model: Any, total_timesteps: int, dp: PrivateTraining, budget: float) -> int:
    """The last env step count whose planned draws stay within ``budget`` (bisection on the plan)."""
    ledger = dp.ledger

    def fits(steps: int) -> bool:
        return planned_epsilon(model, steps, ledger.noise_multiplier, ledger.delta) <= budget

    lo, hi = 0, total_timesteps
    while hi - lo > max(model.n_envs, 1):
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if fits(mid) else (lo, mid)
    return lo

