"""Constrained RL on SB3: PPO-Lagrangian, SAC-Lagrangian and PID-Lagrangian (``info["cost"]`` per step, an
episode-cost limit).

>>> model = PPOLagrangian("MlpPolicy", env, cost_limit=0.1, constraint="pid", multiplier_kwargs={"ki": 0.1})
"""

from sbagents.constrained.buffers import CostRolloutBuffer, CostRolloutBufferSamples
from sbagents.constrained.lagrangian import LagrangeMultiplier, PIDLagrangeMultiplier
from sbagents.constrained.ppo_lagrangian import PPOLagrangian
from sbagents.constrained.sac_lagrangian import CostReplayBuffer, SACLagrangian

__all__ = [
    "CostReplayBuffer",
    "CostRolloutBuffer",
    "CostRolloutBufferSamples",
    "LagrangeMultiplier",
    "PIDLagrangeMultiplier",
    "PPOLagrangian",
    "SACLagrangian",
]
