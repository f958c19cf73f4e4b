"""Goal-conditioned pick and place with a gripper: ``sbagents/KukaPickAndPlace-v0`` and its robust variant.

Not in the book's code (whose arm has no gripper, see :mod:`sbagents.envs.kuka.envs`): the task chapter 5
describes, in panda-gym's ``PickAndPlace`` form, for SB3's ``HerReplayBuffer``. The Kuka iiwa carries the
parallel jaw of :mod:`sbagents.envs.kuka.gripper`; it must lift a cube and put it on a 3-D target.
Spec: docs/envs.md (KukaPickAndPlace, RobustKukaPickAndPlace).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import spaces

from sbagents.envs.kuka.base import POS_BOUND, XYZ, KukaEnvBase, RobustDefaults, ZoneSpec, attribute_ranges
from sbagents.envs.kuka.gripper import MAX_WIDTH, TCP_ABOVE_TIPS, KukaGripper
from sbagents.envs.kuka.pick_task import PickTask
from sbagents.envs.kuka.robot import READY_POSE
from sbagents.envs.kuka.sim import BulletSim
from sbagents.envs.kuka.tasks import dense_goal_reward, sparse_goal_reward

#: Bound of every observed velocity coordinate (m/s, rad/s); observations are clipped to it.
VEL_BOUND = 5.0
#: Bullet's solver stops iterating below this residual (PyBullet's default 1e-7): 24% more env steps/s with random
#: actions, and the scripted picker's success is unchanged (seeds 100-299: 100% nominal, 99.5% robust).
SOLVER_RESIDUAL = 1e-4
#: Duration of one env step (s): 24 Hz control, as the push envs.
CONTROL_PERIOD = 1.0 / 24.0
#: Depth (m) of the TCP below the cube's centre in a ``start_in_hand`` grip (the scripted picker's grasp depth).
HOLD_DEPTH = 0.005


class KukaPickAndPlaceEnv(KukaEnvBase):
    """The Kuka iiwa with a parallel jaw picks a cube and places it on a 3-D target (Dict obs, for HER).

    Observation ``observation`` Box(19): TCP position (3), TCP velocity (3), finger width (1), observed cube
    position (3, with ``noise_level`` noise), cube orientation (3, Euler), cube linear (3) and angular (3)
    velocity; ``achieved_goal`` = true cube position (3,); ``desired_goal`` = target (3,). Action Box(-1, 1,
    (4,)): TCP displacement ``action[:3] * ee_step`` (inverse kinematics, tool down, fixed yaw) and finger
    width change ``action[3] * finger_step`` (panda-gym). Reward: :meth:`compute_reward` only. Never
    terminated; truncated after ``max_steps``.

    :param reward_type: ``"sparse"`` (``-(d > 0.05)``, default) or ``"dense"`` (``-d``).
    :param max_steps: steps before truncation (panda-gym: 50).
    :param n_substeps: physics steps per action; the control period stays :data:`CONTROL_PERIOD` (1/24 s), so
        the physics time step is ``CONTROL_PERIOD / n_substeps`` (default 8: 1/192 s; 10, the push envs' 1/240 s,
        costs ~15% more CPU per env step for the same scripted-picker success).
    :param noise_level: std (m) of Gaussian noise on the observed cube position.
    :param scale_range: per-episode uniform cube scale range, ``None`` for 1.
    :param mass_range: per-episode uniform cube mass range (kg), ``None`` for 0.1 kg.
    :param safety_zone: ``None``, ``"default"``, ``"book"``, ``"path"`` or ``(low, high)`` corners of a box
        the TCP must not enter.
    :param zone_mode: ``"block"`` (a step into the zone is undone) or ``"cost"`` (applied); both report
        ``info["cost"] = 1`` and ``info["violation"] = "safety_zone"`` (the reward stays the goal reward).
    :param object_xy: centre of the cube's and the target's squares.
    :param object_range: half width of the cube's start square.
    :param target_range: half width of the target's square.
    :param target_height: range of the target's height above the resting cube.
    :param table_probability: probability of a target on the table.
    :param ee_step: metres of TCP displacement per unit action.
    :param finger_step: metres of finger-width change per unit action.
    :param ee_low: lower corner of the box TCP targets are clipped to (its z keeps the fingertips 2 mm
        above the table).
    :param ee_high: upper corner of that box.
    :param start_in_hand: probability (default 0) that an episode starts with the cube already held in the closed
        jaw at a height drawn as the target's, above its start: the HER paper's way of making a pick-and-place
        learnable (Andrychowicz et al. 2017 start half of the training episodes so). A training aid: evaluate with
        0 (a zoo entry's ``eval_env_kwargs``).
    :param render_mode: ``"rgb_array"`` (headless TinyRenderer, ``(240, 320, 3)`` uint8) or ``"human"``.
    """

    robot: KukaGripper

    def __init__(
        self,
        reward_type: str = "sparse",
        max_steps: int = 50,
        n_substeps: int = 8,
        noise_level: float = 0.0,
        scale_range: Sequence[float] | None = None,
        mass_range: Sequence[float] | None = None,
        safety_zone: ZoneSpec = None,
        zone_mode: str = "block",
        object_xy: Sequence[float] = (0.6, 0.0),
        object_range: float = 0.15,
        target_range: float = 0.15,
        target_height: Sequence[float] = (0.0, 0.2),
        table_probability: float = 0.3,
        ee_step: float = 0.05,
        finger_step: float = 0.2,
        ee_low: Sequence[float] = (0.2, -0.5, TCP_ABOVE_TIPS + 0.002),
        ee_high: Sequence[float] = (0.9, 0.5, 0.6),
        start_in_hand: float = 0.0,
        render_mode: str | None = None,
    ) -> None:
        if reward_type not in ("sparse", "dense"):
            raise ValueError(f"reward_type must be 'sparse' or 'dense', got {reward_type!r}")
        if not 0.0 <= start_in_hand <= 1.0:
            raise ValueError(f"start_in_hand must be a probability in [0, 1], got {start_in_hand}")
        self.start_in_hand = float(start_in_hand)
        self._init_common(max_steps, safety_zone, zone_mode, render_mode)
        self.reward_type = reward_type
        self.ee_step = float(ee_step)
        self.finger_step = float(finger_step)
        self.ee_low = np.asarray(ee_low, dtype=np.float64)
        self.ee_high = np.asarray(ee_high, dtype=np.float64)
        if n_substeps < 1:
            raise ValueError(f"n_substeps must be >= 1, got {n_substeps}")
        self.sim = BulletSim(
            render_mode=render_mode,
            time_step=CONTROL_PERIOD / n_substeps,
            n_substeps=n_substeps,
            solver_residual=SOLVER_RESIDUAL,
        )
        self.plane = self.sim.load_urdf("plane.urdf")
        self.robot = KukaGripper(self.sim)
        self.task = PickTask(
            self.sim,
            object_xy=object_xy,
            object_range=object_range,
            target_range=target_range,
            target_height=target_height,
            table_probability=table_probability,
            scale_range=scale_range,
            mass_range=mass_range,
            noise_level=noise_level,
        )
        self.attribute_ranges = attribute_ranges(scale_range, mass_range)
        self.action_space = spaces.Box(-1.0, 1.0, (4,), dtype=np.float32)
        self.action_names: tuple[str, ...] = (*(f"d_ee_{a}" for a in XYZ), "d_finger_width")
        self.obs_names: tuple[str, ...] = (
            *(f"ee_{a}" for a in XYZ),
            *(f"ee_v{a}" for a in XYZ),
            "finger_width",
            *(f"object_{a}" for a in XYZ),
            "object_roll",
            "object_pitch",
            "object_yaw",
            *(f"object_v{a}" for a in XYZ),
            *(f"object_w{a}" for a in XYZ),
        )
        goal = spaces.Box(-POS_BOUND, POS_BOUND, (3,), dtype=np.float32)
        self.observation_space = spaces.Dict(
            {
                "observation": spaces.Box(-POS_BOUND, POS_BOUND, (len(self.obs_names),), dtype=np.float32),
                "achieved_goal": goal,
                "desired_goal": goal,
            }
        )
        self.steps = 0
        inf = np.inf
        #: Per-coordinate clip bounds of ``observation`` (the finger width and Euler angles are not clipped).
        self._obs_bound = np.array(
            [POS_BOUND] * 3 + [VEL_BOUND] * 3 + [inf] + [POS_BOUND] * 3 + [inf] * 3 + [VEL_BOUND] * 6
        )
        self._object_position = np.zeros(3)

    # ------------------------------------------------------------- gym API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Soft reset: arm to the ready pose, jaw open; cube scale/mass/start and target from ``np_random``."""
        super().reset(seed=seed)
        self.steps = 0
        self.robot.reset(READY_POSE)
        self.robot.reset_fingers(MAX_WIDTH)
        self.task.reset(self.np_random)
        if self.start_in_hand > 0 and self.np_random.random() < self.start_in_hand:
            self._hold_cube()
        return self._get_obs(), self._info(violation=None)

    def _hold_cube(self) -> None:
        """Put the cube in the closed jaw, lifted above its start by a height drawn as the target's, and let one
        control period of physics settle the grip."""
        task, robot = self.task, self.robot
        start = task.object_position()
        centre = np.array([start[0], start[1], task.half_size + self.np_random.uniform(*task.target_height)])
        tcp = np.clip(centre - np.array([0.0, 0.0, HOLD_DEPTH]), self.ee_low, self.ee_high)
        robot.reset(robot.inverse_kinematics(tcp))
        centre += robot.ee_position() - tcp  # the cube where the jaw actually is
        self.sim.set_base_pose(task.block, centre)
        robot.reset_fingers(2 * task.half_size)
        robot.set_finger_width(0.0)
        self.sim.step()

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        """Move the TCP by ``action[:3] * ee_step`` and the finger width by ``action[3] * finger_step``."""
        action = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        ee_target = np.clip(self.robot.ee_position() + action[:3] * self.ee_step, self.ee_low, self.ee_high)
        targets = self.robot.inverse_kinematics(ee_target)
        width = self.robot.finger_width() + action[3] * self.finger_step
        violation = "safety_zone" if self._apply(np.append(targets, width)) else None
        self.steps += 1
        obs = self._get_obs()
        reward = float(self.compute_reward(obs["achieved_goal"], obs["desired_goal"], {}))
        truncated = self.steps >= self.max_steps
        if self.render_mode == "human":
            self.render()
        return obs, reward, False, truncated, self._info(violation)

    def _command(self, targets: np.ndarray) -> None:
        """``targets`` ``(8,)``: the arm's 7 joint angles and the finger width."""
        self.robot.set_joint_targets(targets[:7])
        self.robot.set_finger_width(float(targets[7]))

    def _snapshot(self) -> Any:
        robot = self.robot
        return (
            robot.joint_targets,
            robot.finger_target,
            robot.joint_state(),
            robot.finger_state(),
            self.sim.get_base_state(self.task.block),
        )

    def _restore(self, snapshot: Any) -> None:
        joint_targets, finger_target, joints, fingers, block = snapshot
        self.robot.set_joint_state(*joints)
        self.robot.set_finger_state(*fingers)
        self.robot.set_joint_targets(joint_targets)
        self.robot.set_finger_width(finger_target)
        self.sim.set_base_state(self.task.block, block)

    def _get_obs(self) -> dict[str, np.ndarray]:
        # one PyBullet query per body: the TCP's position and velocity, the cube's full base state
        ee, ee_velocity = self.robot.ee_state()
        pos, orn, lin, ang = self.sim.get_base_state(self.task.block)
        position = np.array(pos)
        observed = position
        if self.task.noise_level > 0:
            observed = position + self.np_random.normal(0.0, self.task.noise_level, 3)
        observation = np.concatenate(
            [
                ee,
                ee_velocity,
                [self.robot.finger_width()],
                observed,
                self.task.client.getEulerFromQuaternion(orn),
                lin,
                ang,
            ]
        )
        # the bounds in observation order: POS (3), VEL (3), width (unbounded), POS (3), angles, VEL (6)
        observation = np.clip(observation, -self._obs_bound, self._obs_bound)
        self._object_position = position
        return {
            "observation": observation.astype(np.float32),
            "achieved_goal": np.clip(position, -POS_BOUND, POS_BOUND).astype(np.float32),
            "desired_goal": self.task.target.astype(np.float32),
        }

    def _info(self, violation: str | None) -> dict[str, Any]:
        """Per-step info; the cube position is the one :meth:`_get_obs` just read."""
        distance = float(np.linalg.norm(self._object_position - self.task.target))
        return {
            "is_success": distance < self.task.distance_threshold,
            "violation": violation,
            "cost": 1.0 if violation else 0.0,
            "object_scale": self.task.scale,
            "object_mass": self.task.mass,
            "distance": distance,
        }

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        """Vectorised reward ``(..., 3), (..., 3) -> (...)`` float32: ``-(d > 0.05)`` or ``-d``.

        :param achieved_goal: cube positions.
        :param desired_goal: targets.
        :param info: unused (a dict or a batch of dicts, as HER passes it).
        """
        if self.reward_type == "dense":
            return dense_goal_reward(achieved_goal, desired_goal)
        return sparse_goal_reward(achieved_goal, desired_goal, self.task.distance_threshold)


class RobustKukaPickAndPlaceEnv(RobustDefaults, KukaPickAndPlaceEnv):
    """Chapter 6's perturbations on the pick and place: observation noise, cube scale and mass, safety zone.

    Same parameters as :class:`KukaPickAndPlaceEnv`, with the chapter's defaults: ``noise_level=0.05``,
    ``scale_range=(0.5, 1.5)``, ``mass_range=(0.1, 1.0)``, ``safety_zone="default"``.
    """
