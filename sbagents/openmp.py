"""Process-wide OpenMP setting of the training commands, applied before torch is imported.

With more than one torch thread, OpenMP's idle threads spin for a while after each parallel region (the default
``OMP_WAIT_POLICY``), on the same cores as the env's own threads (EnvPool's workers) and the main thread that steps
the envs. On a 2-core machine, with 8 envs, that made ``train --algo pqn --env PongNoFrameskip-v4 --num-threads 2``
three times slower than one thread (a probe); with ``PASSIVE`` idle threads sleep. At 128 envs spinning measured
faster (``python -m benchmarks run pqn-pong-speed``: 1.68x vs 1.49x the 1-thread baseline, one round), so the setting
trades a collapse at few envs for about 12% at many. OpenMP reads the variable once, when torch loads it, so the
commands set it before their imports; a value set by the user is kept.
"""

from __future__ import annotations

import os

#: The variable and the value the training commands give it unless it is set.
WAIT_POLICY = ("OMP_WAIT_POLICY", "PASSIVE")


def passive_wait_policy() -> bool:
    """Set ``OMP_WAIT_POLICY=PASSIVE`` unless the environment already sets it; True when this call set it.

    Has an effect only before torch (or anything else that loads OpenMP) is imported.
    """
    name, value = WAIT_POLICY
    if name in os.environ:
        return False
    os.environ[name] = value
    return True
