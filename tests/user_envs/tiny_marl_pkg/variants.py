"""Variants of ``relay_v0`` that a configuration cannot train, for the one-line error tests (``--env
tiny_marl_pkg.variants:<function>``). Each returns a working ``ParallelEnv``; only its declared spaces or its
``state()`` differ from the relay:

- :func:`grid_scout`: the scout observes its 4 numbers as a ``(2, 2, 1)`` grid, so its observation cannot be
  padded into the workers' vectors (``policies: shared`` is refused).
- :func:`steering_scout`: the scout acts in ``Box(-1, 1, (1,))`` (its action is rounded to a cue index), which DQN
  cannot do.
- :func:`stateless`: ``state()`` is not implemented (``critic: centralized`` is refused).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo.utils.wrappers import BaseParallelWrapper

from tiny_marl_pkg.relay_v0 import SCOUT, parallel_env

GRID = spaces.Box(0.0, 1.0, (2, 2, 1), np.float32)
STEER = spaces.Box(-1.0, 1.0, (1,), np.float32)


class _GridScout(BaseParallelWrapper):
    def observation_space(self, agent: str) -> spaces.Space[Any]:
        return GRID if agent == SCOUT else self.env.observation_space(agent)

    def _reshape(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {a: o.reshape(GRID.shape) if a == SCOUT else o for a, o in obs.items()}

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        obs, infos = self.env.reset(seed=seed, options=options)
        return self._reshape(obs), infos

    def step(self, actions: dict[str, Any]) -> Any:
        obs, *rest = self.env.step(actions)
        return (self._reshape(obs), *rest)


class _SteeringScout(BaseParallelWrapper):
    def action_space(self, agent: str) -> spaces.Space[Any]:
        return STEER if agent == SCOUT else self.env.action_space(agent)

    def step(self, actions: dict[str, Any]) -> Any:
        fixed = dict(actions)
        if SCOUT in fixed:
            fixed[SCOUT] = int(np.clip(np.round(float(np.ravel(fixed[SCOUT])[0]) + 1.0), 0, 2))
        return self.env.step(fixed)


class _Stateless(BaseParallelWrapper):
    def state(self) -> np.ndarray:
        raise NotImplementedError("this env has no global state")


def grid_scout(**kwargs: Any) -> BaseParallelWrapper:
    """The relay with the scout's observation as a ``(2, 2, 1)`` grid."""
    return _GridScout(parallel_env(**kwargs))


def steering_scout(**kwargs: Any) -> BaseParallelWrapper:
    """The relay with a continuous scout action."""
    return _SteeringScout(parallel_env(**kwargs))


def stateless(**kwargs: Any) -> BaseParallelWrapper:
    """The relay without ``state()``."""
    return _Stateless(parallel_env(**kwargs))
