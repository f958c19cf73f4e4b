"""Turn-based games: PettingZoo AEC envs whose observations are ``{"observation", "action_mask"}`` dicts.

A game is named like any PettingZoo env: by its module (``pettingzoo.classic.connect_four_v3``, a module with
``env(**kwargs)``) or by ``module:callable`` returning an ``AECEnv``. Its short name (``connect_four_v3``) is the
run dirs' and config entries' env id, and the key of the built-in opponents (:mod:`sbagents.games.builtin`).
"""

from __future__ import annotations

import importlib
import os
import re
from collections.abc import Callable
from typing import Any

import numpy as np
from gymnasium import spaces

from sbagents.errors import UsageError

#: Keys of an ``observe()`` dict that make an AEC env a game sbagents can train with masks.
OBS_KEY, MASK_KEY = "observation", "action_mask"


def game_factory(source: str) -> Callable[..., Any]:
    """The ``(**kwargs) -> AECEnv`` that ``source`` names (``module`` -> its ``env``)."""
    module_name, _, attr = source.partition(":")
    module = importlib.import_module(module_name)
    return getattr(module, attr or "env")  # type: ignore[no-any-return]


#: Games with an equivalent faster implementation in sbagents (step for step the same env), by source.
FAST_GAMES = {"pettingzoo.classic.connect_four_v3": "sbagents.games.fast_connect_four:env"}


def make_game(source: str, modules: tuple[str, ...] = (), **kwargs: Any) -> Any:
    """Import ``modules`` (user packages), then build the AEC env ``source`` names with ``kwargs``.

    A game of :data:`FAST_GAMES` is built from its faster equivalent unless ``SBAGENTS_REFERENCE_GAMES=1``.
    """
    for name in modules:
        importlib.import_module(name)
    if source in FAST_GAMES and os.environ.get("SBAGENTS_REFERENCE_GAMES") != "1":
        return game_factory(FAST_GAMES[source])(**kwargs)
    return game_factory(source)(**kwargs)


def game_name(source: str) -> str:
    """The short name of a game source: the module's last component, or the callable's name."""
    module_name, _, attr = source.partition(":")
    return attr or module_name.rpartition(".")[2]


def base_game_name(name: str) -> str:
    """``connect_four_v3`` -> ``connect_four`` (built-in opponents match every version)."""
    return re.sub(r"_v\d+$", "", name)


def masked_spaces(env: Any, name: str, algo_hint: str = "ppo_mask") -> tuple[spaces.Box, spaces.Discrete]:
    """The learner's spaces of an AEC game: its ``observation`` sub-space as float32, and its Discrete actions.

    :raises UsageError: the game has no ``{observation, action_mask}`` Dict observations or no Discrete actions
        (such AEC envs cannot be trained with masks; say which algos fit).
    """
    agent = env.possible_agents[0]
    obs_space, act_space = env.observation_space(agent), env.action_space(agent)
    if not (isinstance(obs_space, spaces.Dict) and {OBS_KEY, MASK_KEY} <= set(obs_space.spaces)
            and isinstance(obs_space[OBS_KEY], spaces.Box) and isinstance(act_space, spaces.Discrete)):
        raise UsageError(
            f"{name} is a turn-based env without action masks (observation {obs_space}); {algo_hint} needs "
            "Dict observations {observation: Box, action_mask} and Discrete actions. Turn-based envs without "
            "masks are not trainable here; parallel PettingZoo envs train with ppo, a2c, dqn and the other algos")
    inner = obs_space[OBS_KEY]
    assert isinstance(inner, spaces.Box)
    box = spaces.Box(np.asarray(inner.low, np.float32), np.asarray(inner.high, np.float32), inner.shape,
                     np.float32)
    return box, act_space
