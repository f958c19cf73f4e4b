"""One copy of a PettingZoo ``ParallelEnv`` with the episode bookkeeping SB3 needs: which agents acted, which
slots ended, terminal observations, auto-reset when the episode is over, team episode statistics.

Any ``ParallelEnv`` works: agents may leave early (they stop appearing in ``env.agents``, like KAZ's dead
knights) or arrive later; the episode is over when ``env.agents`` is empty or every agent is done. Declared
episode metrics come from ``env.metadata["info_metrics"]``: a list of info keys (the value at the episode's last
step) or a mapping ``{key: "last" | "sum"}`` (``sum``: summed over agents and steps).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pettingzoo import ParallelEnv

METRIC_RULES = ("last", "sum")


def declared_metrics(metadata: Mapping[str, Any] | None) -> dict[str, str]:
    """``{info key: "last" | "sum"}`` from an env's ``metadata["info_metrics"]`` (empty when it declares none).

    :raises ValueError: a declaration that is not a list of keys or a mapping to ``last``/``sum``.
    """
    spec = (metadata or {}).get("info_metrics") or {}
    rules = {str(k): "last" for k in spec} if isinstance(spec, list | tuple) else dict(spec)
    bad = {k: v for k, v in rules.items() if v not in METRIC_RULES}
    if bad:
        raise ValueError(f"metadata['info_metrics'] rules must be one of {METRIC_RULES}, got {bad}")
    return rules


@dataclass
class CopyStep:
    """What one step of an :class:`EnvCopy` produced, by agent.

    :param obs: the observation each agent present after the step sees (the new episode's first observation
        after an auto-reset).
    :param rewards: this step's reward of every agent that acted.
    :param acted: agents whose action was used this step (present before the step).
    :param done: agents whose episode ended this step (terminated, truncated or left), with ``truncated`` for
        those that were truncated and not terminated.
    :param terminal_obs: the last observation of every agent in ``done``.
    :param infos: the env's info per agent of this step (for agents that acted or ended).
    :param episode: the finished team episode's statistics when the episode ended this step, else None:
        ``r`` (team return), ``l`` (steps), ``t`` (seconds since the copy was made), ``returns`` (per agent) and
        the declared metrics.
    :param state: ``env.state()`` after the step (before an auto-reset: the terminal state; None without state).
    :param reset_state: the state after an auto-reset (None when no reset happened or without state).
    """

    obs: dict[str, Any]
    rewards: dict[str, float]
    acted: set[str]
    done: set[str]
    truncated: set[str]
    terminal_obs: dict[str, Any]
    infos: dict[str, dict[str, Any]]
    episode: dict[str, Any] | None = None
    state: np.ndarray | None = None
    reset_state: np.ndarray | None = None
    reset_infos: dict[str, dict[str, Any]] = field(default_factory=dict)


class EnvCopy:
    """One ``ParallelEnv`` plus its episode bookkeeping (see the module docstring).

    :param env_fn: zero-argument constructor of the env.
    :param with_state: call ``env.state()`` after every reset and step (centralized critics).
    """

    def __init__(self, env_fn: Callable[[], ParallelEnv], with_state: bool = False) -> None:
        self.env = env_fn()
        self.possible_agents = [str(a) for a in self.env.possible_agents]
        self.with_state = with_state
        self.metrics = declared_metrics(getattr(self.env, "metadata", None))
        self._t_start = time.time()
        self._start_episode()

    def _start_episode(self) -> None:
        self._returns = dict.fromkeys(self.possible_agents, 0.0)
        self._length = 0
        self._sums: dict[str, Any] = dict.fromkeys(self.metrics, 0)
        self._last: dict[str, Any] = {}

    def state(self) -> np.ndarray | None:
        """``env.state()`` when asked for (``with_state``), else None."""
        return np.asarray(self.env.state()) if self.with_state else None

    def reset(self, seed: int | None = None, options: Mapping[str, Any] | None = None
              ) -> tuple[dict[str, Any], dict[str, dict[str, Any]], np.ndarray | None]:
        """Reset the env; returns the observations, infos and state of the new episode."""
        obs, infos = self.env.reset(seed=seed, options=dict(options) if options else None)
        self._start_episode()
        return dict(obs), {a: dict(i) for a, i in infos.items()}, self.state()

    def step(self, actions: Mapping[str, Any]) -> CopyStep:
        """Step with the actions of the agents present (others are ignored); auto-reset when the episode ends."""
        acted = {a for a in self.env.agents}
        obs, rewards, terms, truncs, infos = self.env.step({a: actions[a] for a in self.env.agents})
        self._length += 1
        rew = {a: float(rewards.get(a, 0.0)) for a in acted}
        for agent, r in rew.items():
            self._returns[agent] += r
        done = {a for a in acted if terms.get(a, False) or truncs.get(a, False) or a not in self.env.agents}
        truncated = {a for a in done if truncs.get(a, False) and not terms.get(a, False)}
        step_infos = {a: dict(infos.get(a, {})) for a in acted}
        self._track_metrics(step_infos)
        ended = not self.env.agents or all(terms.get(a, False) or truncs.get(a, False) for a in self.env.agents)
        if ended:  # the agents still listed are done too (an env may keep listing them after the last step)
            done |= {a for a in self.env.agents}
        result = CopyStep(dict(obs), rew, acted, done, truncated, {a: obs[a] for a in done if a in obs},
                          step_infos, state=self.state())
        for agent in done - set(result.terminal_obs):  # an agent that left without a final observation
            result.terminal_obs[agent] = None
        if ended:
            result.episode = self._episode_stats()
            new_obs, result.reset_infos, result.reset_state = self.reset()
            result.obs = new_obs
        else:
            result.obs = {a: o for a, o in obs.items() if a in self.env.agents}
        return result

    def _track_metrics(self, infos: dict[str, dict[str, Any]]) -> None:
        for key, rule in self.metrics.items():
            values = [i[key] for i in infos.values() if key in i]  # the env's own number types
            if not values:
                continue
            if rule == "sum":
                self._sums[key] += sum(values)
            else:
                self._last[key] = values[-1]

    def _episode_stats(self) -> dict[str, Any]:
        stats: dict[str, Any] = {
            "r": round(sum(self._returns.values()), 6),
            "l": self._length,
            "t": round(time.time() - self._t_start, 6),
            "returns": dict(self._returns),
        }
        for key, rule in self.metrics.items():
            stats[key] = self._sums[key] if rule == "sum" else self._last.get(key, float("nan"))
        return stats

    def close(self) -> None:
        """Close the env."""
        self.env.close()
