"""Whether a team's agents compete: their rewards sum to zero at every step (rock-paper-scissors), so a team return
says nothing and one shared policy plays every side."""

from __future__ import annotations

from typing import Any

#: Steps of random play :func:`zero_sum_under_random_play` looks at.
PROBE_STEPS = 200


def sums_to_zero(values: list[float]) -> bool:
    """Whether ``values`` (one reward or return per agent) sum to zero, up to float rounding."""
    return abs(sum(values)) <= 1e-6 * (1.0 + max(abs(v) for v in values))


def zero_sum_under_random_play(env: Any, steps: int = PROBE_STEPS, seed: int = 0) -> bool:
    """Whether the rewards of the PettingZoo ``ParallelEnv`` ``env`` sum to zero at every one of ``steps`` steps of
    uniform random actions (reset with ``seed``, and again when every agent is done), some of them not zero.

    The env is stepped: pass a copy built for the check (it is not closed here).
    """
    env.reset(seed=seed)
    for i, agent in enumerate(env.possible_agents):  # each its own stream: equal seeds would mirror the agents
        env.action_space(agent).seed(seed + i)
    seen = False
    for _ in range(steps):
        if not env.agents:
            env.reset()
        actions = {agent: env.action_space(agent).sample() for agent in env.agents}
        _, rewards, _, _, _ = env.step(actions)
        values = [float(r) for r in rewards.values()]
        if len(values) < 2 or not sums_to_zero(values):
            return False
        seen = seen or any(v != 0.0 for v in values)
    return seen
