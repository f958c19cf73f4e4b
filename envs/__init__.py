"""Pure environments of sbagents: Gymnasium ``Env`` classes and PettingZoo ``ParallelEnv`` classes.

No training code lives here. Gymnasium IDs are registered by :mod:`sbagents.registration`
when ``sbagents`` is imported.
"""

from sbagents.envs.gridworld import GridWorldEnv

__all__ = ["GridWorldEnv"]
