"""Keeping time-limit truncation apart from termination in RLlib's multi-agent episodes.

RLlib 2.60's ``MultiAgentEpisode.add_env_step`` declares an episode *terminated* as soon as every agent is done,
and then marks every agent that is done at that step as terminated too, even when the env truncated all of them
(PettingZoo's ``max_cycles``). PPO's GAE then treats the last state of every truncated episode as terminal (no
``V(s_T)`` bootstrap), so the value function learns values that depend on the time left, which the observation
does not show. Measured on ``mpe2.simple_spread_v3`` (25-step episodes, gamma 0.95): the value of the last state
is a third of the discounted return that follows it, and training stalls near -55 where SB3's PPO reaches -28.

The fix has two parts, both used by :func:`sbagents.rllib.experiment.build_config`:

- :class:`PettingZooEnv` reports an agent that terminates as not truncated (Gymnasium's rule: termination wins),
  so "terminated and truncated" can only come from RLlib's own marking;
- :func:`keep_truncation`, an ``on_sample_end`` callback on the env runners, clears ``is_terminated`` of every
  agent episode that is also truncated before the episodes reach the learner.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv


class PettingZooEnv(ParallelPettingZooEnv):
    """RLlib's ``ParallelPettingZooEnv`` with an agent that terminates never also reported as truncated."""

    def step(self, action_dict: dict[Any, Any]) -> Any:  # RLlib's 5-tuple of dicts keyed by agent id
        """One parallel step; ``terminateds``/``truncateds`` carry ``__all__`` as in RLlib's wrapper."""
        obs, rewards, terminateds, truncateds, infos = self.par_env.step(action_dict)
        truncateds = {a: bool(t) and not terminateds.get(a, False) for a, t in truncateds.items()}
        terminateds["__all__"] = all(terminateds.values())
        truncateds["__all__"] = all(truncateds.values())
        return obs, rewards, terminateds, truncateds, infos


def untruncated_terminals(episodes: Iterable[Any]) -> int:
    """Clear ``is_terminated`` of every agent episode that is also truncated; returns how many were cleared.

    :param episodes: RLlib ``MultiAgentEpisode`` objects (single-agent episodes are left alone).
    """
    fixed = 0
    for episode in episodes:
        for agent_episode in getattr(episode, "agent_episodes", {}).values():
            if agent_episode.is_terminated and agent_episode.is_truncated:
                agent_episode.is_terminated = False
                fixed += 1
    return fixed


def keep_truncation(*, samples: list[Any], **kwargs: Any) -> None:
    """``on_sample_end`` callback (``AlgorithmConfig.callbacks``): see :func:`untruncated_terminals`."""
    untruncated_terminals(samples)
