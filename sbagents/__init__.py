"""sbagents: the book's environments and agents as registered, trainable software on Stable-Baselines3.

Importing the package registers the Gymnasium IDs (``sbagents/GridWorld-v0``, ...), so
``gym.make("sbagents:sbagents/GridWorld-v0")`` works in a fresh interpreter. :func:`register_pettingzoo_env` gives a
PettingZoo env of your package a short name for ``--env``; :func:`register_extension` adds a training feature of yours
to ``train`` (:mod:`sbagents.extensions`).
"""

from sbagents.core.extensions import register_extension
from sbagents.registration import GYM_ENVS, register_envs, register_pettingzoo_env

__version__ = "0.1.0"

register_envs()

__all__ = ["GYM_ENVS", "__version__", "register_envs", "register_extension", "register_pettingzoo_env"]
