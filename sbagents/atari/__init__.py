"""Atari at engine speed: EnvPool's C++ Atari behind SB3's ``VecEnv`` API (``--vec-env envpool``).

:mod:`sbagents.atari.envpool_support` decides whether an experiment can run on EnvPool (an ``<Game>NoFrameskip-v4``
id whose only env wrapper is SB3's ``AtariWrapper``) without importing EnvPool;
:mod:`sbagents.atari.envpool_vec_env` is the VecEnv (imported only when one is built). EnvPool is optional: the
``atari`` extra installs it (``pip install "sbagents[atari]"``).
"""

from __future__ import annotations

from sbagents.atari.envpool_support import (
    ATARI_EXTRA_HINT,
    AtariSettings,
    envpool_installed,
    envpool_problems,
    training_vec_env,
)

__all__ = ["ATARI_EXTRA_HINT", "AtariSettings", "envpool_installed", "envpool_problems", "training_vec_env"]
