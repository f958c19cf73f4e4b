"""A user's own env kind, defined outside sbagents (tests/test_env_kinds_open.py): ``--env noisy/<Gymnasium id>``
trains the Gymnasium env with Gaussian noise on its observations. Importing this module registers the kind."""

from __future__ import annotations

import functools
from typing import Any

import gymnasium as gym
import numpy as np

from sbagents.core.env_kinds import EnvKind, SingleAgentKind, load_kind_operations, register_env_kind
from sbagents.core.env_names import EnvRef

PREFIX = "noisy/"


class _Noise(gym.ObservationWrapper):
    def __init__(self, env: gym.Env, std: float = 0.01) -> None:
        super().__init__(env)
        self.std = std

    def observation(self, observation: Any) -> Any:
        noise = self.np_random.normal(0.0, self.std, np.shape(observation))
        return np.asarray(observation + noise, dtype=self.observation_space.dtype)


def make_noisy(inner: str, **kwargs: Any) -> gym.Env:
    """The inner Gymnasium env with observation noise (picklable through functools.partial)."""
    return _Noise(gym.make(inner, **kwargs))


class NoisyKind(EnvKind):
    """Gymnasium envs with observation noise, named ``noisy/<id>``."""

    name = "noisy"

    def claim(self, name: str, modules: tuple[str, ...]) -> EnvRef | None:
        if name.startswith(PREFIX) and name[len(PREFIX):] in gym.registry:
            return EnvRef(name, self, modules=(*modules, __name__))
        return None

    def config_entries(self, ref: EnvRef) -> tuple[str, ...]:
        return (ref.env_id, ref.env_id[len(PREFIX):])

    def observation_spaces(self, ref: EnvRef, env_kwargs: dict[str, Any]) -> list[Any]:
        env = make_noisy(ref.env_id[len(PREFIX):], **env_kwargs)
        try:
            return [env.observation_space]
        finally:
            env.close()


NOISY = NoisyKind()
operations = load_kind_operations()
own = {
    "sbagents.env_construction._constructor": lambda kind, ref: functools.partial(make_noisy, ref.env_id[len(PREFIX):]),
    "sbagents.env_construction.env_fn": lambda kind, ref: functools.partial(make_noisy, ref.env_id[len(PREFIX):]),
}
for qualified, op in operations.items():  # a Gymnasium env after all: the single-agent behaviour, but our envs
    op.register(NoisyKind, own.get(qualified, op.dispatch(SingleAgentKind)))
register_env_kind(NOISY)
