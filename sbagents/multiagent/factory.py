"""A picklable constructor of one copy of a PettingZoo env: its source, keyword arguments and wrappers.

Worker processes (``--vec-env subproc``) rebuild copies from it, so it holds names and data only: the env's
``source`` (``pkg.module`` or ``pkg.module:callable``), the modules to import first, and the wrapper classes
(picklable by reference).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
from pettingzoo import AECEnv

from sbagents.core.env_names import make_parallel_env
from sbagents.errors import UsageError


def check_parallel_wrappers(wrappers: Sequence[tuple[Any, dict[str, Any]]]) -> None:
    """Raise :class:`UsageError` for a wrapper class that wraps something else than a ``ParallelEnv`` (a Gymnasium
    wrapper such as ``AtariWrapper``, or a PettingZoo AEC wrapper), before any env is built."""
    for wrapper, _ in wrappers:
        for base, kind in ((gym.Env, "a Gymnasium wrapper (of gymnasium.Env)"), (AECEnv, "a PettingZoo AEC wrapper")):
            if isinstance(wrapper, type) and issubclass(wrapper, base):
                raise UsageError(f"env_wrapper {wrapper.__module__}.{wrapper.__qualname__} is {kind}; PettingZoo envs "
                                 "take ParallelEnv wrappers, e.g. sbagents.multiagent.preprocessing.ImagePreprocessing")


class ParallelEnvFactory:
    """``wrapper_n(...wrapper_1(make_parallel_env(source, modules, **kwargs)))`` as a zero-argument callable.

    :param source: the env's ``pkg.module`` (with ``parallel_env``) or ``pkg.module:callable``.
    :param modules: modules to import first (``--gym-packages``).
    :param kwargs: the env's constructor keywords.
    :param wrappers: ``(wrapper class or function, keyword arguments)`` applied in order (PettingZoo parallel
        wrappers: the config's ``env_wrapper``).
    :raises UsageError: a Gymnasium or AEC wrapper class among ``wrappers`` (:func:`check_parallel_wrappers`).
    """

    def __init__(self, source: str, modules: Sequence[str] = (), kwargs: dict[str, Any] | None = None,
                 wrappers: Sequence[tuple[Any, dict[str, Any]]] = ()) -> None:
        self.source, self.modules = source, tuple(modules)
        self.kwargs = dict(kwargs or {})
        check_parallel_wrappers(wrappers)
        self.wrappers = list(wrappers)

    def __call__(self) -> Any:
        env = make_parallel_env(self.source, self.modules, **self.kwargs)
        for wrapper, wrapper_kwargs in self.wrappers:
            env = wrapper(env, **wrapper_kwargs)
        return env
