"""``mpe2.simple_spread_v3``'s parallel env on the batched arrays: :class:`SimpleSpreadParallelEnv`, one copy of
:class:`~sbagents.batched.simple_spread.BatchedSimpleSpreadVecEnv` behind PettingZoo's ``ParallelEnv`` API.

Step for step equal to ``mpe2.simple_spread_v3.parallel_env(**env_kwargs)`` as sbagents builds it (batchable
kwargs, no rendering; mpe2's env under :class:`~sbagents.batched.spread_metrics.SpreadMetricsWrapper`):
observations, float64 rewards, terminations (never), truncations at ``max_cycles`` (then ``agents`` is empty), infos
(empty, but for the team metrics :data:`~sbagents.batched.spread_metrics.SPREAD_METRICS` at the last step, declared
in ``metadata["info_metrics"]``), ``state()`` and seeding (``reset(seed=s)`` seeds the generator as mpe2 does;
``reset()`` continues it). It skips mpe2's AEC round trip and per-agent Python loops, which makes every path that
steps PettingZoo env copies (``per_group``, ``agent_id``, ``critic: centralized``, RLlib's env runners) several
times faster on this env.
:func:`sbagents.core.env_names.make_parallel_env` uses it wherever the kwargs allow (:func:`array_parallel_env`,
listed in :data:`sbagents.registration.ARRAY_IMPLEMENTATIONS`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from sbagents.batched.simple_spread import BatchedSimpleSpreadVecEnv, unsupported_kwargs
from sbagents.batched.spread_metrics import SPREAD_METRICS


class SimpleSpreadParallelEnv(ParallelEnv):  # type: ignore[misc]
    """``mpe2.simple_spread_v3.parallel_env(**env_kwargs)``, stepped on arrays (see the module docstring).

    :raises ValueError: kwargs the batched env does not reproduce (continuous actions, a render mode, ...).
    """

    def __init__(self, **env_kwargs: Any) -> None:
        self._vec = BatchedSimpleSpreadVecEnv(1, env_kwargs)
        template = self._vec.template
        self.possible_agents: list[str] = list(template.possible_agents)
        self.agents: list[str] = []
        self.observation_spaces = {a: template.observation_space(a) for a in self.possible_agents}
        self.action_spaces = {a: template.action_space(a) for a in self.possible_agents}
        self.state_space: spaces.Space[Any] = template.state_space
        self.metadata = {**template.metadata, "info_metrics": dict(SPREAD_METRICS)}
        self.render_mode = None
        self.max_cycles = self._vec.max_cycles
        self._started = False
        self._next_start_drawn = False  # the auto-reset at the episode end drew the next start already
        self._terminal: np.ndarray | None = None  # (N, obs_dim) after the last step of an episode

    def observation_space(self, agent: str) -> spaces.Space[Any]:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Space[Any]:
        return self.action_spaces[agent]

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """Start an episode (``seed`` reseeds the generator; options are ignored, as mpe2 ignores them)."""
        if seed is not None:
            self._vec.seed(seed)
        if seed is not None or not self._started or not self._next_start_drawn:
            self._vec.reset()  # draws a start from the (re)seeded or continuing generator, as mpe2's reset
        self._started, self._next_start_drawn, self._terminal = True, False, None
        self.agents = list(self.possible_agents)
        obs = self._vec._observe()[0]
        return {a: obs[j] for j, a in enumerate(self.possible_agents)}, {a: {} for a in self.possible_agents}

    def step(self, actions: dict[str, Any]) -> tuple[dict[str, np.ndarray], dict[str, float], dict[str, bool],
                                                      dict[str, bool], dict[str, dict[str, Any]]]:
        """Move every agent (``actions``: agent -> ``0..4``); at ``max_cycles`` all are truncated and leave."""
        if not self.agents:
            raise RuntimeError("simple_spread: the episode is over; call reset()")
        self._vec.step_async(np.array([int(actions[a]) for a in self.possible_agents], dtype=np.int64))
        vec_obs, _, dones, infos = self._vec.step_wait()
        obs = np.asarray(vec_obs)  # (N, obs_dim): one copy's agents
        rewards = self._vec.last_rewards[0]
        done = bool(dones[0])
        step_infos: dict[str, dict[str, Any]] = {a: {} for a in self.possible_agents}
        if done:  # the VecEnv reset itself: report the episode's last observations, keep the drawn start
            obs = np.stack([info["terminal_observation"] for info in infos])
            self._terminal, self._next_start_drawn = obs, True
            self.agents = []
            step_infos = {a: {key: infos[j][key] for key in SPREAD_METRICS} for j, a in enumerate(self.possible_agents)}
        return ({a: obs[j] for j, a in enumerate(self.possible_agents)},
                {a: float(rewards[j]) for j, a in enumerate(self.possible_agents)},
                dict.fromkeys(self.possible_agents, False), dict.fromkeys(self.possible_agents, done), step_infos)

    def state(self) -> np.ndarray:
        """Every agent's observation, concatenated (mpe2's ``state()``), ``(N * obs_dim,)`` float32."""
        obs = self._terminal if self._terminal is not None else self._vec._observe()[0]
        return np.asarray(obs, dtype=np.float32).reshape(-1)

    def close(self) -> None:
        self._vec.close()


def array_parallel_env(**env_kwargs: Any) -> SimpleSpreadParallelEnv | None:
    """:class:`SimpleSpreadParallelEnv` of ``env_kwargs``, or None when they ask for something it does not reproduce
    (or the installed mpe2's world differs from the one reproduced): then mpe2's own env is the one to build."""
    if unsupported_kwargs(env_kwargs):
        return None
    try:
        return SimpleSpreadParallelEnv(**env_kwargs)
    except NotImplementedError:  # an mpe2 whose world differs from the one reproduced
        return None
