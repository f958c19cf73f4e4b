"""Gymnasium registration of the sbagents environment IDs (done once, on ``import sbagents``)."""

from __future__ import annotations

#: Gymnasium ID -> entry point. Multi-agent PettingZoo envs are listed in
#: :data:`sbagents.pipeline.env_names.PETTINGZOO_ENVS` instead.
GYM_ENVS: dict[str, str] = {
    "sbagents/GridWorld-v0": "sbagents.envs.gridworld:GridWorldEnv",
    "sbagents/SmartHome-v0": "sbagents.envs.smart_home:SmartHomeEnv",
    "sbagents/PickAndPlace-v0": "sbagents.envs.kuka:PickAndPlaceEnv",
    "sbagents/RobustPickAndPlace-v0": "sbagents.envs.kuka:RobustPickAndPlaceEnv",
    "sbagents/PickAndPlaceGoal-v0": "sbagents.envs.kuka:PickAndPlaceGoalEnv",
}


def register_envs() -> None:
    """Register every ID in :data:`GYM_ENVS` that is not registered yet (idempotent).

    Does nothing where gymnasium is not installed (an edge device that only runs ``sbagents.serve``).
    """
    try:
        import gymnasium as gym
    except ImportError:
        return
    for env_id, entry_point in GYM_ENVS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=entry_point)
