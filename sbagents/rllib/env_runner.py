"""A leaner ``MultiAgentEnvRunner`` for envs with many short, cheap steps (``mpe2.simple_spread_v3``).

RLlib 2.60's ``MultiAgentEnvRunner._sample`` spends a large share of its time on bookkeeping that does not grow
with what it samples:

- after *every* vector step it calls ``to_numpy()`` on every episode finished so far in the ``sample()`` call
  (each call re-validates every agent's episode), so the cost grows with the square of the episodes per call;
- every env step logs four metric values per agent and two per env into the ``MetricsLogger``, and increments a
  Prometheus counter.

:class:`LeanMultiAgentEnvRunner` samples exactly the same episodes (same actions, observations and random streams)
but numpy-izes each returned episode once, at the end of the call, and logs the step counts of the call in one
``log_value`` per key (the same keys, reductions and totals as RLlib's).
"""

from __future__ import annotations

from collections import Counter
from typing import Any

from ray.rllib.env.multi_agent_env_runner import MultiAgentEnvRunner
from ray.rllib.utils.metrics import (
    NUM_AGENT_STEPS_SAMPLED,
    NUM_AGENT_STEPS_SAMPLED_LIFETIME,
    NUM_ENV_STEPS_SAMPLED,
    NUM_ENV_STEPS_SAMPLED_LIFETIME,
    NUM_EPISODES,
    NUM_EPISODES_LIFETIME,
    NUM_MODULE_STEPS_SAMPLED,
    NUM_MODULE_STEPS_SAMPLED_LIFETIME,
)


class LeanMultiAgentEnvRunner(MultiAgentEnvRunner):  # type: ignore[misc]
    """RLlib's ``MultiAgentEnvRunner`` with per-call (not per-step) numpy conversion and step-count logging."""

    episodes_to_numpy: bool  # RLlib's EnvRunner attribute (declared for type checkers that cannot see Ray)

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._counts: dict[str, Counter[str]] = {"env": Counter(), "agent": Counter(), "module": Counter()}
        self._prometheus: dict[int, tuple[Any, int]] = {}  # id(counter) -> (counter, pending increments)
        super().__init__(*args, **kwargs)

    def _increase_sampled_metrics(self, num_steps: int, next_obs: dict[Any, Any], episode: Any) -> int:
        """Count the env step (and a finished episode, and its agents' and modules' steps) for the next flush."""
        env = self._counts["env"]
        env["steps"] += num_steps
        if episode.is_done:
            env["episodes"] += 1
        for aid in next_obs:
            self._counts["agent"][str(aid)] += 1
            self._counts["module"][episode.module_for(aid)] += 1
        return num_steps

    def _log_env_steps(self, metric: Any, num_steps: int) -> None:
        """Defer the Prometheus counter increment to the end of the ``sample()`` call."""
        counter, pending = self._prometheus.get(id(metric), (metric, 0))
        self._prometheus[id(metric)] = (counter, pending + num_steps)

    def _sample(self, **kwargs: Any) -> list[Any]:
        """RLlib's ``_sample`` without its per-step numpy conversion; converts the returned episodes and logs the
        counted steps once."""
        to_numpy, self.episodes_to_numpy = self.episodes_to_numpy, False
        try:
            episodes: list[Any] = super()._sample(**kwargs)
        finally:
            self.episodes_to_numpy = to_numpy
            self._flush_counts()
        if to_numpy:
            for episode in episodes:
                episode.to_numpy()
        return episodes

    def _flush_counts(self) -> None:
        """Log the counts gathered since the last flush (RLlib's keys and reductions) and reset them."""
        env, log = self._counts["env"], self.metrics.log_value
        if env["steps"]:
            log(NUM_ENV_STEPS_SAMPLED, env["steps"], reduce="sum")
            log(NUM_ENV_STEPS_SAMPLED_LIFETIME, env["steps"], reduce="lifetime_sum", with_throughput=True)
        if env["episodes"]:
            log(NUM_EPISODES, env["episodes"], reduce="sum")
            log(NUM_EPISODES_LIFETIME, env["episodes"], reduce="lifetime_sum")
        for kind, now, lifetime in (("agent", NUM_AGENT_STEPS_SAMPLED, NUM_AGENT_STEPS_SAMPLED_LIFETIME),
                                    ("module", NUM_MODULE_STEPS_SAMPLED, NUM_MODULE_STEPS_SAMPLED_LIFETIME)):
            for key, n in self._counts[kind].items():
                log((now, key), n, reduce="sum")
                log((lifetime, key), n, reduce="lifetime_sum")
        for counts in self._counts.values():
            counts.clear()
        for counter, pending in self._prometheus.values():
            if pending > 0:
                super()._log_env_steps(counter, pending)
        self._prometheus.clear()
