"""Baseline policies with SB3's ``predict`` signature: uniform random actions, and one scripted controller per copy of
a VecEnv."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any, Protocol

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv

from sbagents.errors import UsageError


def batch_size(obs: Any) -> int:
    """The copies in a batch of observations (a ``Dict`` observation: of its first key)."""
    if isinstance(obs, dict):
        return len(next(iter(obs.values())))
    return len(obs)


def slot(obs: Any, i: int) -> Any:
    """Copy ``i``'s observation of a batch."""
    return {key: value[i] for key, value in obs.items()} if isinstance(obs, dict) else obs[i]


class RandomPolicy:
    """Uniform random actions of ``action_space`` (its ``sample()``), one per copy of the batch.

    :param action_space: the action space of one copy.
    :param seed: seeds the space's sampler (None: unseeded).
    """

    def __init__(self, action_space: spaces.Space[Any], seed: int | None = None) -> None:
        self.action_space = action_space
        self.action_space.seed(seed)

    def predict(self, obs: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        """``(actions of shape (n_copies, *action_shape), state)``; ``deterministic`` does not apply."""
        return np.stack([np.asarray(self.action_space.sample()) for _ in range(batch_size(obs))]), state


class Controller(Protocol):
    """A scripted expert of one env: built on the env (it may read its true state), reset at each episode's start."""

    def reset(self) -> None:
        """Forget the episode."""
        ...

    def act(self, obs: Any) -> Any:
        """The action for ``obs`` (one copy's observation)."""
        ...


class ControllerPolicy:
    """One controller per copy of a ``DummyVecEnv`` (each built on its own copy, which it may read), with SB3's
    ``predict``: a copy whose episode starts resets its controller first.

    :param venv: the VecEnv the policy acts in (its base must be a ``DummyVecEnv``).
    :param make: builds the controller of one copy (the env with its wrappers).
    :raises UsageError: a VecEnv whose copies live in other processes or are batched.
    """

    def __init__(self, venv: VecEnv, make: Callable[[gym.Env[Any, Any]], Controller]) -> None:
        envs = getattr(venv.unwrapped, "envs", None)
        if envs is None:
            raise UsageError(f"scripted policies read their env: they run on DummyVecEnv copies, not on a "
                             f"{type(venv.unwrapped).__name__}")
        self.controllers = [make(env) for env in envs]

    def predict(self, obs: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        """``(actions, state)``; ``episode_start`` (default: every copy starts) resets those copies' controllers."""
        n = batch_size(obs)
        starts = np.ones(n, dtype=bool) if episode_start is None else np.asarray(episode_start, dtype=bool)
        actions = []
        for i, controller in enumerate(self.controllers[:n]):
            if starts[i]:
                controller.reset()
            actions.append(np.asarray(controller.act(slot(obs, i))))
        return np.stack(actions), state


def scripted_policy(env_id: str, venv: VecEnv) -> Any:
    """The scripted expert of ``env_id`` acting in ``venv``, with SB3's ``predict``
    (:data:`sbagents.registration.SCRIPTED_POLICIES`): a controller per copy (:class:`ControllerPolicy`), or a policy
    built on the VecEnv itself where the expert's class says ``acts_on_vec_env`` (a team's).

    :raises UsageError: an env without one (naming the envs that have one).
    """
    from sbagents.registration import SCRIPTED_POLICIES

    path = SCRIPTED_POLICIES.get(env_id)
    if path is None:
        raise UsageError(f"{env_id} has no scripted expert; --policy scripted plays one for "
                         f"{', '.join(SCRIPTED_POLICIES)} (and the built-in players of turn-based games); "
                         "--policy random plays any env")
    module, _, name = path.partition(":")
    factory = getattr(importlib.import_module(module), name)
    if getattr(factory, "acts_on_vec_env", False):
        return factory(venv)
    return ControllerPolicy(venv, factory)
