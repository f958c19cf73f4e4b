"""Kuka iiwa pick-and-place environments on PyBullet (sim / robot / task split as in panda-gym).

Entry points: ``sbagents.envs.kuka:PickAndPlaceEnv``, ``sbagents.envs.kuka:RobustPickAndPlaceEnv``,
``sbagents.envs.kuka:PickAndPlaceGoalEnv``.
"""

from sbagents.envs.kuka.envs import KukaPushEnv, PickAndPlaceEnv, RobustPickAndPlaceEnv
from sbagents.envs.kuka.goal import PickAndPlaceGoalEnv
from sbagents.envs.kuka.tasks import SAFETY_ZONES, SafetyZone

__all__ = [
    "SAFETY_ZONES",
    "KukaPushEnv",
    "PickAndPlaceEnv",
    "PickAndPlaceGoalEnv",
    "RobustPickAndPlaceEnv",
    "SafetyZone",
]
