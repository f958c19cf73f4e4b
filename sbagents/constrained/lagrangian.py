"""Lagrange multiplier updaters for constrained RL: gradient ascent and PID (Stooke et al. 2020).

Both solve ``max_pi J_r(pi)  s.t.  J_c(pi) <= cost_limit`` by the Lagrangian ``J_r - lambda * (J_c - limit)``:
the policy maximises the penalised return while ``lambda >= 0`` rises while the episode cost ``J_c`` is above the
limit and falls back toward 0 when it is below. Each ``update(ep_cost)`` takes one measurement of ``J_c`` (the
mean undiscounted episode cost of a rollout) and returns the new multiplier; ``history`` keeps one dict per update
(``timesteps``, ``ep_cost``, ``multiplier``) for logs and ``safety.json``.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any


def _plain_float(value: Any) -> float | None:
    """A finite number from a JSON value or its text, else None."""
    if isinstance(value, bool):
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def _check_finite(name: str, value: float, minimum: float | None = 0.0) -> float:
    value = float(value)
    if not math.isfinite(value) or (minimum is not None and value < minimum):
        bound = "" if minimum is None else f" >= {minimum}"
        raise ValueError(f"{name} must be a finite number{bound}, got {value!r}")
    return value


class LagrangeMultiplier:
    """PPO-Lagrangian's multiplier (Ray et al. 2019): projected gradient ascent on ``lambda``.

    ``lambda <- max(0, lambda + lr * (ep_cost - cost_limit))``.

    :param cost_limit: the episode-cost budget ``d`` (same units as the summed ``info["cost"]``).
    :param lr: step size of the ascent.
    :param init: initial multiplier (>= 0).
    :param max_multiplier: upper clamp of ``lambda`` (``inf``: none).
    """

    def __init__(self, cost_limit: float, lr: float = 0.05, init: float = 0.0, max_multiplier: float = math.inf):
        self.cost_limit = _check_finite("cost_limit", cost_limit)
        self.lr = _check_finite("lr", lr)
        self.value = _check_finite("init", init)
        if not max_multiplier >= self.value:
            raise ValueError(f"max_multiplier must be >= init, got {max_multiplier!r}")
        self.max_multiplier = float(max_multiplier)
        self.history: list[dict[str, Any]] = []

    def update(self, ep_cost: float, timesteps: int | None = None) -> float:
        """One ascent step from a measured mean episode cost; returns the new multiplier.

        :param ep_cost: mean episode cost ``J_c`` of the latest rollout.
        :param timesteps: environment steps so far, recorded in ``history`` (default: the number of updates).
        """
        ep_cost = _check_finite("ep_cost", ep_cost, minimum=None)
        self.value = min(self.max_multiplier, max(0.0, self.value + self.lr * (ep_cost - self.cost_limit)))
        self._record(ep_cost, timesteps)
        return self.value

    #: The attributes that change as it learns (restored from a saved model's plain description).
    STATE: tuple[str, ...] = ("value",)

    def restore(self, saved: Any) -> None:
        """Take the learned state of a saved multiplier from SB3's plain description of it (its attributes as JSON
        values or text): the numbers of :attr:`STATE` and ``history``; anything malformed is ignored (the model
        then starts from its configured ``init``).
        """
        if not isinstance(saved, dict):
            return
        for name in self.STATE:
            value = _plain_float(saved.get(name))
            if value is not None:
                setattr(self, name, value)
        history = saved.get("history")
        if isinstance(history, list) and len(history) <= 1_000_000:
            self.history = [
                {"timesteps": int(h["timesteps"]), "ep_cost": float(h["ep_cost"]), "multiplier": float(h["multiplier"])}
                for h in history
                if isinstance(h, dict) and all(_plain_float(h.get(k)) is not None
                                               for k in ("timesteps", "ep_cost", "multiplier"))
            ]
        self.value = min(self.max_multiplier, max(0.0, self.value))

    def _record(self, ep_cost: float, timesteps: int | None) -> None:
        step = len(self.history) + 1 if timesteps is None else int(timesteps)
        self.history.append({"timesteps": step, "ep_cost": ep_cost, "multiplier": self.value})


class PIDLagrangeMultiplier(LagrangeMultiplier):
    """PID-Lagrangian multiplier (Stooke, Achiam & Abbeel 2020, Algorithm 2; OmniSafe's ``PIDLagrangian``).

    With the error ``e = ep_cost - cost_limit``:

    - P: ``kp * e_ema``, ``e_ema`` an exponential moving average of ``e`` (weight ``p_ema_alpha`` on the past);
    - I: ``I <- max(0, I + ki * e)`` (clamped at 0: no windup below the limit);
    - D: ``kd * max(0, c_ema - c_ema[delay updates ago])`` on the EMA of the *cost* (not the error), so only a
      rising cost pushes ``lambda`` up;
    - ``lambda = clip(kp * e_ema + I + kd * D, 0, max_multiplier)``.

    With ``kp = kd = 0`` it is :class:`LagrangeMultiplier` with ``lr = ki``.

    :param cost_limit: the episode-cost budget.
    :param kp: proportional gain.
    :param ki: integral gain.
    :param kd: derivative gain.
    :param init: initial value of the integral term (and so of ``lambda``).
    :param d_delay: number of updates between the two costs the derivative compares (>= 1).
    :param p_ema_alpha: EMA weight on the past for the proportional error (0: none).
    :param d_ema_alpha: EMA weight on the past for the cost the derivative uses (0: none).
    :param max_multiplier: upper clamp of ``lambda`` (OmniSafe's ``penalty_max``).
    """

    def __init__(
        self,
        cost_limit: float,
        kp: float = 0.1,
        ki: float = 0.01,
        kd: float = 0.01,
        init: float = 0.0,
        d_delay: int = 10,
        p_ema_alpha: float = 0.95,
        d_ema_alpha: float = 0.95,
        max_multiplier: float = 100.0,
    ):
        super().__init__(cost_limit, lr=ki, init=init, max_multiplier=max_multiplier)
        self.kp = _check_finite("kp", kp)
        self.ki = _check_finite("ki", ki)
        self.kd = _check_finite("kd", kd)
        if int(d_delay) < 1:
            raise ValueError(f"d_delay must be >= 1, got {d_delay!r}")
        for name, alpha in (("p_ema_alpha", p_ema_alpha), ("d_ema_alpha", d_ema_alpha)):
            if not 0.0 <= alpha < 1.0:
                raise ValueError(f"{name} must be in [0, 1), got {alpha!r}")
        self.d_delay = int(d_delay)
        self.p_ema_alpha = float(p_ema_alpha)
        self.d_ema_alpha = float(d_ema_alpha)
        self.integral = self.value
        self.error_ema = 0.0
        self.cost_ema = 0.0
        self.cost_emas: deque[float] = deque([0.0], maxlen=self.d_delay)
        self.derivative = 0.0

    STATE = ("value", "integral", "error_ema", "cost_ema", "derivative")

    def restore(self, saved: Any) -> None:
        super().restore(saved)
        text = saved.get("cost_emas") if isinstance(saved, dict) else None
        if isinstance(text, str) and text.startswith("deque([") and len(text) < 1 << 16:
            values = [_plain_float(v) for v in text[len("deque(["):].split("]")[0].split(",") if v.strip()]
            if values and all(v is not None for v in values):
                self.cost_emas = deque((float(v) for v in values if v is not None), maxlen=self.d_delay)

    def update(self, ep_cost: float, timesteps: int | None = None) -> float:
        """One PID step from a measured mean episode cost; returns the new multiplier (see the class docstring)."""
        ep_cost = _check_finite("ep_cost", ep_cost, minimum=None)
        error = ep_cost - self.cost_limit
        self.integral = max(0.0, self.integral + self.ki * error)
        self.error_ema = self.p_ema_alpha * self.error_ema + (1.0 - self.p_ema_alpha) * error
        self.cost_ema = self.d_ema_alpha * self.cost_ema + (1.0 - self.d_ema_alpha) * ep_cost
        self.derivative = max(0.0, self.cost_ema - self.cost_emas[0])
        output = self.kp * self.error_ema + self.integral + self.kd * self.derivative
        self.value = min(self.max_multiplier, max(0.0, output))
        self.cost_emas.append(self.cost_ema)
        self._record(ep_cost, timesteps)
        return self.value


#: ``--constraint`` methods and their multiplier classes (constrained algorithms build ``MULTIPLIERS[method]``).
MULTIPLIERS: dict[str, type[LagrangeMultiplier]] = {"lagrangian": LagrangeMultiplier, "pid": PIDLagrangeMultiplier}
