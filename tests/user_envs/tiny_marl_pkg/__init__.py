"""A user's own PettingZoo env package for the multi-agent tests: importing it registers ``relay_v0``.

``relay_v0`` (module :mod:`tiny_marl_pkg.relay_v0`, PettingZoo's ``parallel_env`` / ``raw_env`` / ``env``
layout) has heterogeneous agents (a scout with a 4-number observation, two workers with 3) sharing the action
space ``Discrete(3)``; the scout leaves the episode early. See that module for the rules.

Only :func:`sbagents.registration.register_pettingzoo_env` is imported here, so naming the package with
``--gym-packages`` is cheap; the env module itself (and PettingZoo) is imported when the env is built.
"""

from __future__ import annotations

from sbagents.registration import register_pettingzoo_env

register_pettingzoo_env("relay_v0", "tiny_marl_pkg.relay_v0")
