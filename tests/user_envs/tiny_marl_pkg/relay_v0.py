"""``relay_v0``: a tiny heterogeneous PettingZoo env in which one agent leaves early (PettingZoo's layout).

Agents ``scout_0``, ``worker_0``, ``worker_1`` all act in ``Discrete(3)``. Each step every live agent sees a
one-hot *cue* of length 3 (drawn per agent per step from ``self.np_random``) and gets reward +1 if its action
equals the index of the cue it saw, else 0. Observations: workers ``Box(0, 1, (3,))`` = the cue; the scout
``Box(0, 1, (4,))`` = the cue, then its remaining-lifetime fraction ``(scout_steps - t) / scout_steps``.

The scout is terminated after ``scout_steps`` steps (5) and then removed from ``agents``; the workers are
truncated after ``max_cycles`` steps (10), which empties ``agents``. Optimal returns: ``scout_steps`` for the
scout and ``max_cycles`` for each worker; a uniform random policy gets a third of that.

``state()`` (``Box(0, 1, (10,))``): the three agents' current cues in ``possible_agents`` order (zeros for an
agent no longer in ``agents``), then the step fraction ``t / max_cycles``. ``infos[agent]["correct"]`` is 1 if
the agent's action this step matched its cue, else 0, on every step (not at reset); summed over an episode it is
the number of correct actions (``metadata["info_metrics"]``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import AECEnv, ParallelEnv
from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_to_aec

__all__ = ["ACCEPTED_KWARGS", "Relay", "env", "parallel_env", "raw_env"]

#: Keyword arguments accepted by :class:`Relay` (and :func:`parallel_env`).
ACCEPTED_KWARGS: tuple[str, ...] = ("scout_steps", "max_cycles", "render_mode")
N_CUES = 3
SCOUT = "scout_0"


class Relay(ParallelEnv):
    """The relay env (rules in the module docstring).

    :param scout_steps: steps after which the scout is terminated (>= 1).
    :param max_cycles: steps after which the workers are truncated (>= ``scout_steps``).
    :param render_mode: ``None`` or ``"ansi"`` (``render()`` returns one line of text).
    """

    metadata: dict[str, Any] = {
        "name": "relay_v0",
        "render_modes": ["ansi"],
        "is_parallelizable": True,
        "info_metrics": {"correct": "sum"},
    }

    def __init__(self, scout_steps: int = 5, max_cycles: int = 10, render_mode: str | None = None) -> None:
        if scout_steps < 1:
            raise ValueError(f"scout_steps must be >= 1, got {scout_steps}")
        if max_cycles < scout_steps:
            raise ValueError(f"max_cycles must be >= scout_steps ({scout_steps}), got {max_cycles}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.scout_steps, self.max_cycles, self.render_mode = int(scout_steps), int(max_cycles), render_mode
        self.possible_agents = [SCOUT, "worker_0", "worker_1"]
        self.agents = list(self.possible_agents)
        self.observation_spaces = {
            a: spaces.Box(0.0, 1.0, (N_CUES + 1 if a == SCOUT else N_CUES,), np.float32) for a in self.possible_agents
        }
        self.action_spaces = {a: spaces.Discrete(N_CUES) for a in self.possible_agents}
        self.state_space = spaces.Box(0.0, 1.0, (N_CUES * len(self.possible_agents) + 1,), np.float32)
        self.np_random, _ = seeding.np_random(None)
        self.steps = 0
        self.cues: dict[str, int] = {}
        self.last_actions: dict[str, int] = {}
        self.last_cues: dict[str, int] = {}

    def observation_space(self, agent: str) -> spaces.Space[Any]:
        """The agent's observation space (the same object on every call)."""
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Space[Any]:
        """The agent's action space, ``Discrete(3)`` (the same object on every call)."""
        return self.action_spaces[agent]

    def _draw_cues(self) -> None:
        self.cues = {a: int(self.np_random.integers(N_CUES)) for a in self.agents}

    def _observe(self, agent: str) -> np.ndarray:
        obs = np.zeros(self.observation_spaces[agent].shape, np.float32)
        obs[self.cues[agent]] = 1.0
        if agent == SCOUT:
            obs[N_CUES] = max(self.scout_steps - self.steps, 0) / self.scout_steps
        return obs

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """Start an episode with all three agents; ``seed`` reseeds ``np_random``. ``options`` is ignored."""
        if seed is not None:
            self.np_random, _ = seeding.np_random(seed)
        self.agents = list(self.possible_agents)
        self.steps = 0
        self.last_actions, self.last_cues = {}, {}
        self._draw_cues()
        return {a: self._observe(a) for a in self.agents}, {a: {} for a in self.agents}

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[dict[str, np.ndarray], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict[str, Any]]]:
        """Reward every live agent for matching its cue; the scout leaves at ``scout_steps``, all at ``max_cycles``.

        :raises RuntimeError: before :meth:`reset` or after the episode ended.
        :raises ValueError: an action is missing, invalid, or given for an agent that is not live.
        """
        if not self.agents or not self.cues:
            raise RuntimeError("relay_v0: no live agents; call reset() first")
        if set(actions) != set(self.agents):
            raise ValueError(f"relay_v0: need one action for each live agent {self.agents}, got {sorted(actions)}")
        for agent, action in actions.items():
            if not self.action_spaces[agent].contains(action):
                raise ValueError(f"relay_v0: invalid action {action!r} for {agent}")
        self.last_cues = dict(self.cues)
        self.last_actions = {a: int(actions[a]) for a in self.agents}
        correct = {a: int(self.last_actions[a] == self.last_cues[a]) for a in self.agents}
        rewards = {a: float(c) for a, c in correct.items()}
        infos: dict[str, dict[str, Any]] = {a: {"correct": c} for a, c in correct.items()}
        self.steps += 1
        self._draw_cues()
        observations = {a: self._observe(a) for a in self.agents}
        terminations = {a: a == SCOUT and self.steps >= self.scout_steps for a in self.agents}
        truncations = {a: self.steps >= self.max_cycles and not terminations[a] for a in self.agents}
        self.agents = [a for a in self.agents if not (terminations[a] or truncations[a])]
        return observations, rewards, terminations, truncations, infos

    def state(self) -> np.ndarray:
        """Global state: each agent's one-hot cue (zeros once it left), then ``steps / max_cycles``."""
        state = np.zeros(self.state_space.shape, np.float32)
        for i, agent in enumerate(self.possible_agents):
            if agent in self.agents and agent in self.cues:
                state[N_CUES * i + self.cues[agent]] = 1.0
        state[-1] = min(self.steps / self.max_cycles, 1.0)
        return state

    def render(self) -> str | None:
        """``"ansi"``: one line with the step and each agent's cue and action of the last step; else ``None``."""
        if self.render_mode != "ansi":
            return None
        parts = [f"step {self.steps}/{self.max_cycles}"]
        for agent in self.possible_agents:
            if agent in self.last_actions:
                parts.append(f"{agent} cue={self.last_cues[agent]} action={self.last_actions[agent]}")
            elif agent in self.agents and agent in self.cues:
                parts.append(f"{agent} cue={self.cues[agent]} action=-")
            else:
                parts.append(f"{agent} gone")
        return " | ".join(parts)

    def close(self) -> None:
        """Nothing to release."""


def parallel_env(**kwargs: Any) -> Relay:
    """The native parallel env; ``kwargs`` as :class:`Relay`.

    :raises TypeError: an unknown keyword argument (the message names the accepted ones).
    """
    unknown = sorted(set(kwargs) - set(ACCEPTED_KWARGS))
    if unknown:
        raise TypeError(f"relay_v0: unknown keyword argument(s) {unknown}; accepted: {', '.join(ACCEPTED_KWARGS)}")
    return Relay(**kwargs)


def raw_env(**kwargs: Any) -> AECEnv:
    """AEC version of :func:`parallel_env` (``parallel_to_aec``) without the checking wrappers."""
    return parallel_to_aec(parallel_env(**kwargs))


def env(**kwargs: Any) -> AECEnv:
    """AEC env with PettingZoo's standard wrappers (out-of-bounds actions and call order asserted)."""
    return wrappers.OrderEnforcingWrapper(wrappers.AssertOutOfBoundsWrapper(raw_env(**kwargs)))
