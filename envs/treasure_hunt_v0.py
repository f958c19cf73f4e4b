"""PettingZoo entry module for CooperativeTreasureHunt (``sbagents.envs.treasure_hunt_v0``).

Follows PettingZoo's layout: :func:`parallel_env` builds the native ``ParallelEnv``, :func:`raw_env` its
AEC conversion (``parallel_to_aec``) and :func:`env` the AEC env with PettingZoo's usual wrappers
(``AssertOutOfBoundsWrapper``, ``OrderEnforcingWrapper``). See :mod:`sbagents.envs.treasure_hunt`
for the rules, observation layouts and keyword arguments.
"""

from __future__ import annotations

from typing import Any

from pettingzoo import AECEnv
from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_to_aec

from sbagents.envs.treasure_hunt import ACCEPTED_KWARGS, CooperativeTreasureHunt

__all__ = ["ACCEPTED_KWARGS", "CooperativeTreasureHunt", "env", "parallel_env", "raw_env"]


def _check_kwargs(kwargs: dict[str, Any]) -> None:
    unknown = sorted(set(kwargs) - set(ACCEPTED_KWARGS))
    if unknown:
        raise TypeError(
            f"treasure_hunt_v0: unknown keyword argument(s) {unknown}; accepted: {', '.join(ACCEPTED_KWARGS)}"
        )


def parallel_env(**kwargs: Any) -> CooperativeTreasureHunt:
    """The native parallel env; ``kwargs`` as :class:`CooperativeTreasureHunt` (unknown key -> TypeError)."""
    _check_kwargs(kwargs)
    return CooperativeTreasureHunt(**kwargs)


def raw_env(**kwargs: Any) -> AECEnv:
    """AEC version of :func:`parallel_env` without the checking wrappers."""
    return parallel_to_aec(parallel_env(**kwargs))


def env(**kwargs: Any) -> AECEnv:
    """AEC env with PettingZoo's standard wrappers (out-of-bounds actions and call order asserted)."""
    aec = raw_env(**kwargs)
    aec = wrappers.AssertOutOfBoundsWrapper(aec)
    return wrappers.OrderEnforcingWrapper(aec)
