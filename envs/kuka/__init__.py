"""Kuka iiwa pick-and-place environments on PyBullet (sim / robot / task split as in panda-gym).

Entry points: ``sbagents.envs.kuka:PickAndPlaceEnv``, ``sbagents.envs.kuka:RobustPickAndPlaceEnv``,
``sbagents.envs.kuka:PickAndPlaceGoalEnv`` (pushes, no gripper); ``sbagents.envs.kuka:KukaPickAndPlaceEnv``,
``sbagents.envs.kuka:RobustKukaPickAndPlaceEnv`` (a real pick and place with a parallel-jaw gripper).
"""

from sbagents.envs.kuka.envs import KukaPushEnv, PickAndPlaceEnv, RobustPickAndPlaceEnv
from sbagents.envs.kuka.goal import PickAndPlaceGoalEnv
from sbagents.envs.kuka.pick import KukaPickAndPlaceEnv, RobustKukaPickAndPlaceEnv
from sbagents.envs.kuka.tasks import SAFETY_ZONES, SafetyZone

__all__ = [
    "SAFETY_ZONES",
    "KukaPickAndPlaceEnv",
    "KukaPushEnv",
    "PickAndPlaceEnv",
    "PickAndPlaceGoalEnv",
    "RobustKukaPickAndPlaceEnv",
    "RobustPickAndPlaceEnv",
    "SafetyZone",
]
