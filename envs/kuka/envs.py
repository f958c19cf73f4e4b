"""Gymnasium environments of chapters 5 and 6: Kuka iiwa pushes a block onto a target.

``PickAndPlaceEnv`` (``sbagents/PickAndPlace-v0``), ``RobustPickAndPlaceEnv``
(``sbagents/RobustPickAndPlace-v0``) and the goal-conditioned ``PickAndPlaceGoalEnv``
(``sbagents/PickAndPlaceGoal-v0``, for HER). Spec: docs/envs.md (PickAndPlace, RobustPickAndPlace).

Book behaviour kept: gravity -9.81, plane, fixed-base iiwa at the origin with joints reset to 0,
``block.urdf`` at (0.5, 0), target (0.5, 0.5), observation Box(12) = 6 joint angles + block position +
target position, action Box(-0.1, 0.1, (6,)) joint deltas in position control (targets = measured
angles + action, clipped to [-pi, pi] and the joint limits), rewards -1 per step, +100 and termination
within 0.05 of the target, -10 and termination on a drop, 100 steps; robust variant: observation noise
(std 0.05), block scale U(0.5, 1.5), mass U(0.1, 1.0), -50 for a step into the safety zone.

Deviations (book defects), all documented in the README table:

- ``n_substeps`` (default 10) physics steps of 1/240 s per action instead of one (24 Hz control).
- The target sits at the block's resting height (the arm has no gripper: the task is a push), and the
  block starts at rest on the plane instead of being dropped from z = 0.1.
- One physics client per env; URDFs are loaded once and episodes reset softly (teleports); only the
  robust block is reloaded when its scale changes.
- "Drop" for a push: the block falls below z = -0.05 or leaves the arm's reach (horizontal distance
  to the base > 1 m).
- The 7th joint (flange rotation) is held at 0; it does not move the end-effector point.
- The default safety zone does not contain the target (the book's zone does; ``safety_zone="book"``).
  A step whose commanded pose, or any physics substep of it, puts the end effector in the zone is
  undone (state restored): reward -50, ``info["violation"] = "safety_zone"``, ``info["cost"] = 1``.
- Cost-only zone (``zone_mode="cost"``, Safety-Gym style, not in the book): the step is applied, the
  reward is the task's plus ``zone_penalty`` (default 0), and every step in which the end effector is in
  the zone at any physics substep reports ``info["cost"] = 1`` and ``info["violation"] = "safety_zone"``.
  ``safety_zone="path"`` lies under the ready pose of ``benchmarks/configs/kuka.yml``, across the arm's
  direct way down to the block: a straight move from there to the push start enters it, a detour
  (``ScriptedPusher(via=PATH_DETOUR)``: back over the robot's side first) does not, and with
  ``zone_mode="cost"`` the shorter path (reward) and the zone (cost) conflict.
- Options: ``reward_type="dense"`` (see :meth:`PushTask.dense_reward`) and ``control="ee"``:
  Box(-1, 1, (3,)) Cartesian end-effector deltas of up to ``ee_step`` m per step through inverse
  kinematics with the tool pointing down (as panda-gym and PyBullet's KukaGymEnv); ``object="cube"`` (panda-gym's
  4 cm cube instead of the book's stick) and ``object_xy`` (the start's centre) for panda-gym's randomized
  workspace (``benchmarks/configs/kuka_random.yml``, docs/envs.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import spaces

from sbagents.envs.kuka.base import POS_BOUND, XYZ, KukaEnvBase, RobustDefaults, ZoneSpec, attribute_ranges
from sbagents.envs.kuka.robot import N_CONTROLLED, KukaIiwa
from sbagents.envs.kuka.sim import BulletSim
from sbagents.envs.kuka.tasks import VIOLATION_REWARD, PushTask

JOINT_NAMES = tuple(f"joint_{i + 1}" for i in range(N_CONTROLLED))


class KukaPushEnv(KukaEnvBase):
    """Base class: a Kuka iiwa pushes ``block.urdf`` onto a target (book observation and rewards).

    :param control: ``"joints"`` (book: Box(-0.1, 0.1, (6,)) joint deltas in rad) or ``"ee"``
        (Box(-1, 1, (3,)) end-effector deltas, times ``ee_step`` m, through inverse kinematics).
    :param reward_type: ``"book"`` (-1 / +100 / -10) or ``"dense"`` (distances, see ``PushTask``).
    :param max_steps: steps before truncation.
    :param n_substeps: physics steps (1/240 s each) per action.
    :param noise_level: std (m) of Gaussian noise on the observed block position.
    :param scale_range: per-episode uniform block scale range, ``None`` for 1.
    :param mass_range: per-episode uniform block mass range (kg), ``None`` for the URDF's 0.02 kg.
    :param safety_zone: ``None``, ``"default"``, ``"book"``, ``"path"`` or ``(low, high)`` corners of a box
        the end effector must not enter.
    :param zone_mode: ``"block"`` (a step into the zone is undone and rewarded ``zone_penalty`` instead of
        the task reward) or ``"cost"`` (the step is applied and rewarded the task reward plus
        ``zone_penalty``); both report ``info["cost"] = 1`` and ``info["violation"] = "safety_zone"``.
    :param zone_penalty: reward of a zone step (block mode) or added to it (cost mode); ``None``: -50
        (block, the book's) or 0 (cost: the zone is a constraint only).
    :param object: ``"block"`` (the book's ``block.urdf`` stick) or ``"cube"`` (a 4 cm cube, as panda-gym's push).
    :param object_xy: nominal start ``(x, y)`` of the object (book: (0.5, 0)).
    :param object_range: half width (m) of a uniform random offset of the block's start around ``object_xy``.
    :param target_box: ``((x_lo, y_lo), (x_hi, y_hi))`` to draw a random target per episode.
    :param ee_step: metres per unit action in ``"ee"`` control.
    :param ee_low: lower corner of the box end-effector targets are clipped to (``"ee"`` control); its
        z keeps the pusher's tip 3 mm above the plane.
    :param ee_high: upper corner of that box.
    :param initial_joints: joint angles at reset (book: all 0, the arm stretched up).
    :param render_mode: ``"rgb_array"`` (headless TinyRenderer, ``(240, 320, 3)`` uint8) or ``"human"``.
    """

    def __init__(
        self,
        control: str = "joints",
        reward_type: str = "book",
        max_steps: int = 100,
        n_substeps: int = 10,
        noise_level: float = 0.0,
        scale_range: Sequence[float] | None = None,
        mass_range: Sequence[float] | None = None,
        safety_zone: ZoneSpec = None,
        zone_mode: str = "block",
        zone_penalty: float | None = None,
        object: str = "block",
        object_xy: Sequence[float] = (0.5, 0.0),
        object_range: float = 0.0,
        target_box: Sequence[Sequence[float]] | None = None,
        ee_step: float = 0.05,
        ee_low: Sequence[float] = (-0.9, -0.9, 0.003),
        ee_high: Sequence[float] = (0.9, 0.9, 1.0),
        initial_joints: Sequence[float] = (0.0,) * N_CONTROLLED,
        render_mode: str | None = None,
    ) -> None:
        if control not in ("joints", "ee"):
            raise ValueError(f"control must be 'joints' or 'ee', got {control!r}")
        if reward_type not in self._reward_types():
            raise ValueError(f"reward_type must be one of {self._reward_types()}, got {reward_type!r}")
        if len(initial_joints) != N_CONTROLLED:
            raise ValueError(f"initial_joints needs {N_CONTROLLED} angles, got {len(initial_joints)}")
        self._init_common(max_steps, safety_zone, zone_mode, render_mode)
        self.control = control
        self.reward_type = reward_type
        default_penalty = VIOLATION_REWARD if zone_mode == "block" else 0.0
        self.zone_penalty = default_penalty if zone_penalty is None else float(zone_penalty)
        self.ee_step = float(ee_step)
        self.ee_low = np.asarray(ee_low, dtype=np.float64)
        self.ee_high = np.asarray(ee_high, dtype=np.float64)
        self.initial_joints = np.asarray(initial_joints, dtype=np.float64)
        self.sim = BulletSim(render_mode=render_mode, n_substeps=n_substeps)
        self.plane = self.sim.load_urdf("plane.urdf")
        self.robot = KukaIiwa(self.sim)
        self.task = PushTask(
            self.sim,
            object=object,
            object_xy=object_xy,
            object_range=object_range,
            target_box=target_box,
            scale_range=scale_range,
            mass_range=mass_range,
            noise_level=noise_level,
        )
        self.attribute_ranges = attribute_ranges(scale_range, mass_range)
        if control == "joints":
            self.action_space = spaces.Box(-0.1, 0.1, (N_CONTROLLED,), dtype=np.float32)
            self.action_names: tuple[str, ...] = tuple(f"d_{n}" for n in JOINT_NAMES)
        else:
            self.action_space = spaces.Box(-1.0, 1.0, (3,), dtype=np.float32)
            self.action_names = tuple(f"d_ee_{a}" for a in XYZ)
        self.observation_space = self._make_observation_space()
        self.steps = 0

    # ----------------------------------------------------------- subclassing
    @staticmethod
    def _reward_types() -> tuple[str, ...]:
        return ("book", "dense")

    def _make_observation_space(self) -> spaces.Space[Any]:
        lows = np.concatenate([np.full(N_CONTROLLED, -np.pi), np.full(6, -POS_BOUND)]).astype(np.float32)
        self.obs_names: tuple[str, ...] = (
            JOINT_NAMES + tuple(f"object_{a}" for a in XYZ) + tuple(f"target_{a}" for a in XYZ)
        )
        return spaces.Box(lows, -lows, dtype=np.float32)

    def _get_obs(self) -> Any:
        q = self.robot.joint_angles()[:N_CONTROLLED]
        obj = self.task.observed_object_position(self.np_random)
        obs = np.concatenate([np.clip(q, -np.pi, np.pi), np.clip(obj, -POS_BOUND, POS_BOUND), self.task.target])
        return obs.astype(np.float32)

    def _reward(self, success: bool, dropped: bool, obj: np.ndarray, violation: str | None) -> float:
        if violation and self.zone_mode == "block":
            return self.zone_penalty
        penalty = self.zone_penalty if violation else 0.0
        if self.reward_type == "dense":
            return self.task.dense_reward(success, dropped, self.robot.ee_position(), obj) + penalty
        return self.task.book_reward(success, dropped) + penalty

    def _terminates_on(self, success: bool, dropped: bool) -> bool:
        return success or dropped

    # ------------------------------------------------------------- gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        """Soft reset: joints to ``initial_joints``; block scale/mass/start and target from ``np_random``."""
        super().reset(seed=seed)
        self.steps = 0
        self.robot.reset(self.initial_joints)
        self.task.reset(self.np_random)
        return self._get_obs(), self._info(violation=None, success=False)

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        """Apply one action for ``n_substeps`` physics steps (block mode: undone if it enters the safety zone)."""
        space = self.action_space
        assert isinstance(space, spaces.Box)
        action = np.clip(np.asarray(action, dtype=np.float64), space.low, space.high)
        if self.control == "joints":
            targets = self.robot.joint_delta_targets(action)
        else:
            ee_target = np.clip(self.robot.ee_position() + action * self.ee_step, self.ee_low, self.ee_high)
            targets = self.robot.inverse_kinematics(ee_target)
        violation = "safety_zone" if self._apply(targets) else None
        self.steps += 1
        obj = self.task.object_position()
        success = bool(self.task.is_success(obj, self.task.target))
        dropped = self.task.is_dropped(obj)
        reward = self._reward(success, dropped, obj, violation)
        terminated = self._terminates_on(success, dropped)
        truncated = self.steps >= self.max_steps and not terminated
        if self.render_mode == "human":
            self.render()
        return self._get_obs(), float(reward), terminated, truncated, self._info(violation, success, obj)

    def _command(self, targets: np.ndarray) -> None:
        self.robot.set_joint_targets(targets)

    def _snapshot(self) -> Any:
        return self.robot.joint_targets, self.robot.joint_state(), self.sim.get_base_state(self.task.block)

    def _restore(self, snapshot: Any) -> None:
        joint_targets, joints, block = snapshot
        self.robot.set_joint_state(*joints)
        self.robot.set_joint_targets(joint_targets)
        self.sim.set_base_state(self.task.block, block)

    def _info(self, violation: str | None, success: bool, obj: np.ndarray | None = None) -> dict[str, Any]:
        """Per-step info; ``obj`` is the object position ``(3,)`` if the caller has read it this step."""
        obj = self.task.object_position() if obj is None else obj
        return {
            "is_success": success,
            "violation": violation,
            "cost": 1.0 if violation else 0.0,
            "object_scale": self.task.scale,
            "object_mass": self.task.mass,
            "distance": float(np.linalg.norm(obj - self.task.target)),
        }


class PickAndPlaceEnv(KukaPushEnv):
    """Chapter 5's task with the book's spaces and rewards (see the module docstring for the fixes)."""


class RobustPickAndPlaceEnv(RobustDefaults, KukaPushEnv):
    """Chapter 6: observation noise, random block scale and mass, and a safety zone.

    Same parameters as :class:`KukaPushEnv`, with the chapter's defaults: ``noise_level=0.05``,
    ``scale_range=(0.5, 1.5)``, ``mass_range=(0.1, 1.0)``, ``safety_zone="default"``.
    """
