"""Counting safety violations during training (Safety-Gymnasium's cost conventions) as an SB3 callback."""

from __future__ import annotations

from collections import Counter, deque
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from sbagents.atomic import write_json
from sbagents.callbacks.common import (
    acted_slots,
    agent_layout,
    install_exception_hook,
    output_dir,
    remove_exception_hook,
)
from sbagents.callbacks.episodes import step_violation  # the info-key contract; re-exported

__all__ = ["SAFETY_FILE", "SafetyViolationCallback", "step_violation"]

SAFETY_FILE = "safety.json"


class SafetyViolationCallback(BaseCallback):
    """Count safety violations, log them and stop training when a limit is passed.

    Logged to the SB3 logger (at every rollout end): ``safety/violations`` (total violation steps),
    ``safety/violation_rate`` (violation steps per 1,000 env steps), ``safety/ep_cost`` (mean cost of the
    last ``window`` finished episodes, Safety-Gymnasium's EpCost) and ``safety/cost_rate`` (total cost per
    env step, the Safety Gym paper's cost rate).

    With a multi-agent (team) VecEnv every step of a present agent counts as one step (an agent that left or has
    not arrived takes none), and a team episode's cost is the sum over its agents.

    At training end (also after a stop, and when an exception such as Ctrl-C leaves ``learn``)
    ``safety.json`` is written: ``violations`` per type, ``total_violations``, ``total_steps``,
    ``violation_rate`` (per 1,000 steps), ``total_cost``, ``episodes``, ``ep_cost`` summary (mean, std,
    min, max, last-window mean), the limits, ``stopped`` and ``stop_reason``.

    :param cost_limit: stop when the mean cost of the last ``window`` episodes exceeds it (checked at every
        episode end once ``min_episodes`` episodes are done). PPO-Lagrangian's usual limit is 25.
    :param max_violations: stop when the total number of violation steps exceeds it.
    :param path: directory (or ``.json`` file) for ``safety.json``; None: the SB3 logger's directory.
    :param window: episodes in the running mean episode cost.
    :param min_episodes: episodes needed before ``cost_limit`` is checked.
    """

    def __init__(
        self,
        cost_limit: float | None = None,
        max_violations: int | None = None,
        path: str | Path | None = None,
        window: int = 100,
        min_episodes: int = 1,
        verbose: int = 1,
    ) -> None:
        super().__init__(verbose)
        if window < 1 or min_episodes < 1:
            raise ValueError("window and min_episodes must be >= 1")
        if max_violations is not None and max_violations < 0:
            raise ValueError(f"max_violations must be >= 0, got {max_violations}")
        self.cost_limit = None if cost_limit is None else float(cost_limit)
        self.max_violations = None if max_violations is None else int(max_violations)
        self.path = None if path is None else Path(path)
        self.window, self.min_episodes = int(window), int(min_episodes)
        self.counts: Counter[str] = Counter()
        self.total_steps = 0
        self.total_cost = 0.0
        self.ep_costs: list[float] = []
        self._recent: deque[float] = deque(maxlen=self.window)
        self._ep_cost = np.zeros(0)
        self.stopped = False
        self.stop_reason: str | None = None
        self.saved_path: Path | None = None

    @property
    def total_violations(self) -> int:
        """Violation steps counted so far (all types)."""
        return int(sum(self.counts.values()))

    @property
    def violation_rate(self) -> float:
        """Violation steps per 1,000 env steps."""
        return 1000.0 * self.total_violations / max(self.total_steps, 1)

    def _on_training_start(self) -> None:
        self._n_agents, agents = agent_layout(self.training_env)
        self._team = agents is not None  # a team VecEnv: its team episodes end with SB3's episode info
        n_envs = self.training_env.num_envs // self._n_agents
        if len(self._ep_cost) != n_envs or self.model.num_timesteps == 0:
            self._ep_cost = np.zeros(n_envs)
        install_exception_hook(self.model, self, self.save)

    def _on_step(self) -> bool:
        infos = self.locals["infos"]
        dones = self.locals["dones"]
        acted = acted_slots(infos)
        self.total_steps += int(acted.sum())
        n_agents = self._n_agents
        ended = False
        for k, info in enumerate(infos):
            kind, cost = step_violation(info) if acted[k] else (None, 0.0)
            if kind is not None:
                self.counts[kind] += 1
            if cost:
                self.total_cost += cost
                self._ep_cost[k // n_agents] += cost
            if (k % n_agents == 0 and "episode" in info) if self._team else dones[k]:
                self.ep_costs.append(float(self._ep_cost[k // n_agents]))
                self._recent.append(self.ep_costs[-1])
                self._ep_cost[k // n_agents] = 0.0
                ended = True
        return self._check_limits() if (ended or self.max_violations is not None) else True

    def _check_limits(self) -> bool:
        if self.max_violations is not None and self.total_violations > self.max_violations:
            self._stop(f"{self.total_violations} violation steps > max_violations {self.max_violations}")
        elif (
            self.cost_limit is not None
            and len(self._recent) >= self.min_episodes
            and float(np.mean(self._recent)) > self.cost_limit
        ):
            mean = float(np.mean(self._recent))
            self._stop(
                f"mean episode cost {mean:.3g} over the last {len(self._recent)} episodes > cost_limit "
                f"{self.cost_limit:g}"
            )
        return not self.stopped

    def _stop(self, reason: str) -> None:
        self.stopped = True
        self.stop_reason = f"{reason} after {self.num_timesteps} timesteps; training stopped"
        if self.verbose >= 1:
            print(f"SafetyViolationCallback: {self.stop_reason}")

    def _record(self) -> None:
        self.logger.record("safety/violations", self.total_violations)
        self.logger.record("safety/violation_rate", self.violation_rate)
        self.logger.record("safety/cost_rate", self.total_cost / max(self.total_steps, 1))
        if self._recent:
            self.logger.record("safety/ep_cost", float(np.mean(self._recent)))

    def _on_rollout_end(self) -> None:
        self._record()

    def _on_training_end(self) -> None:
        self._record()
        self.save()
        remove_exception_hook(self.model, self)

    def summary(self) -> dict[str, Any]:
        """The content of ``safety.json``."""
        costs = np.asarray(self.ep_costs, dtype=np.float64)

        def stat(fn: Any) -> float | None:
            return float(fn(costs)) if costs.size else None

        return {
            "violations": dict(sorted(self.counts.items())),
            "total_violations": self.total_violations,
            "total_steps": self.total_steps,
            "violation_rate": self.violation_rate,
            "total_cost": self.total_cost,
            "cost_rate": self.total_cost / max(self.total_steps, 1),
            "episodes": len(self.ep_costs),
            "ep_cost": {
                "mean": stat(np.mean),
                "std": stat(np.std),
                "min": stat(np.min),
                "max": stat(np.max),
                "last_window_mean": float(np.mean(self._recent)) if self._recent else None,
                "window": self.window,
            },
            "cost_limit": self.cost_limit,
            "max_violations": self.max_violations,
            "stopped": self.stopped,
            "stop_reason": self.stop_reason,
        }

    def save(self) -> Path:
        """Write ``safety.json`` (to ``path``, else the logger's dir) and return its path."""
        if self.path is not None and self.path.suffix == ".json":
            self.path.parent.mkdir(parents=True, exist_ok=True)
            target = self.path
        else:
            logger_dir = self.logger.get_dir() if self.model is not None else None
            target = output_dir(self.path, logger_dir) / SAFETY_FILE
        write_json(target, self.summary())
        self.saved_path = target
        return target
