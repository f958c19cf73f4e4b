"""Goal-conditioned push (``sbagents/PickAndPlaceGoal-v0``) for Hindsight Experience Replay.

Not in the book: chapter 5's task in panda-gym's form, so SB3's ``HerReplayBuffer`` can relabel goals.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import spaces

from sbagents.envs.kuka.envs import JOINT_NAMES, POS_BOUND, XYZ, KukaPushEnv
from sbagents.envs.kuka.robot import N_CONTROLLED, READY_POSE


class PickAndPlaceGoalEnv(KukaPushEnv):
    """Push the block to a random target; Dict observation for HER (panda-gym conventions).

    Observation: ``observation`` Box(15) = 6 joint angles, end-effector position, block position
    (plus ``noise_level`` noise), block linear velocity; ``achieved_goal`` = true block position (3,);
    ``desired_goal`` = target (3,). Reward: :meth:`compute_reward` only (sparse ``-(d > 0.05)`` or dense
    ``-d``), so that relabelled transitions get exactly the reward the env would have given. Episodes
    are never terminated (a terminal state with negative rewards would teach the agent to end episodes,
    and HER's relabelled goals would disagree with the stored termination); they are truncated after
    ``max_steps``. ``info`` keeps every contract key (``is_success`` each step, ``cost``, ``violation``,
    ``object_scale``, ``object_mass``); a safety-zone step is undone but its cost is only in ``info``.

    :param control: ``"ee"`` (default, as panda-gym) or ``"joints"``.
    :param reward_type: ``"sparse"`` (default) or ``"dense"``.
    :param max_steps: steps before truncation (panda-gym: 50).
    :param object_range: half width (m) of the random offset of the block's start around ``object_xy``
        (default (0.5, 0), a :class:`~sbagents.envs.kuka.envs.KukaPushEnv` parameter like ``object``).
    :param target_box: ``((x_lo, y_lo), (x_hi, y_hi))`` the target is drawn from each episode (it
        contains the book's target (0.5, 0.5)). panda-gym's randomisation: ``object_range=0.15`` and a
        0.3 m square around the same centre (``benchmarks/configs/kuka_random.yml``).
    :param initial_joints: joint angles at reset: the tool points down 0.46 m above (0.6, 0), as
        panda-gym starts near the table (the book's all-zero pose costs ~25 of the 50 steps).
    :param kwargs: the remaining :class:`~sbagents.envs.kuka.envs.KukaPushEnv` parameters.
    """

    def __init__(
        self,
        control: str = "ee",
        reward_type: str = "sparse",
        max_steps: int = 50,
        object_range: float = 0.05,
        target_box: Sequence[Sequence[float]] | None = ((0.35, -0.15), (0.65, 0.55)),
        initial_joints: Sequence[float] = READY_POSE[:N_CONTROLLED],
        **kwargs: Any,
    ) -> None:
        super().__init__(
            control=control,
            reward_type=reward_type,
            max_steps=max_steps,
            object_range=object_range,
            target_box=target_box,
            initial_joints=initial_joints,
            **kwargs,
        )

    @staticmethod
    def _reward_types() -> tuple[str, ...]:
        return ("sparse", "dense")

    def _make_observation_space(self) -> spaces.Space[Any]:
        self.obs_names = (
            JOINT_NAMES
            + tuple(f"ee_{a}" for a in XYZ)
            + tuple(f"object_{a}" for a in XYZ)
            + tuple(f"object_v{a}" for a in XYZ)
        )
        low = np.concatenate([np.full(N_CONTROLLED, -np.pi), np.full(9, -POS_BOUND)]).astype(np.float32)
        goal = spaces.Box(-POS_BOUND, POS_BOUND, (3,), dtype=np.float32)
        return spaces.Dict(
            {
                "observation": spaces.Box(low, -low, dtype=np.float32),
                "achieved_goal": goal,
                "desired_goal": goal,
            }
        )

    def _get_obs(self) -> dict[str, np.ndarray]:
        q = np.clip(self.robot.joint_angles()[:N_CONTROLLED], -np.pi, np.pi)
        rest = np.concatenate(
            [
                self.robot.ee_position(),
                self.task.observed_object_position(self.np_random),
                self.task.object_velocity(),
            ]
        )
        obs = np.concatenate([q, np.clip(rest, -POS_BOUND, POS_BOUND)]).astype(np.float32)
        achieved = np.clip(self.task.object_position(), -POS_BOUND, POS_BOUND).astype(np.float32)
        return {
            "observation": obs,
            "achieved_goal": achieved,
            "desired_goal": self.task.target.astype(np.float32),
        }

    def _reward(self, success: bool, dropped: bool, obj: np.ndarray, violation: str | None) -> float:
        return float(self.compute_reward(obj, self.task.target, {}))

    def _terminates_on(self, success: bool, dropped: bool) -> bool:
        return False

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        """Vectorised reward ``(..., 3), (..., 3) -> (...)`` float32: ``-(d > 0.05)`` or ``-d``.

        :param achieved_goal: block positions.
        :param desired_goal: targets.
        :param info: unused (a dict or a batch of dicts, as HER passes it).
        """
        if self.reward_type == "dense":
            return self.task.dense_goal_reward(achieved_goal, desired_goal)
        return self.task.sparse_goal_reward(achieved_goal, desired_goal)
