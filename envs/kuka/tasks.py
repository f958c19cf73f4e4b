"""Rules of the push task: the block, the target, success, drop, rewards and the safety zone.

The book calls the task "pick and place", but the Kuka iiwa of ``kuka_iiwa/model.urdf`` has no gripper
and the book's target hovers 7.5 cm above where a resting block can be. We keep the book's names and
put the target at the block's resting height: the task is a push.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sbagents.envs.kuka.sim import BulletSim

#: Half height of ``block.urdf`` (0.10 x 0.018 x 0.018 m) at scale 1.
BLOCK_HALF_HEIGHT = 0.009
#: Mass of ``block.urdf`` in kg.
BLOCK_MASS = 0.02
#: Edge of the ``object="cube"`` option (m), panda-gym's push cube; it weighs :data:`BLOCK_MASS` too.
CUBE_SIZE = 0.04
#: Objects a :class:`PushTask` can push: the book's stick (``block.urdf``) or panda-gym's 4 cm cube.
OBJECTS = ("block", "cube")
#: Rewards of the book (chapters 5 and 6).
STEP_REWARD = -1.0
SUCCESS_REWARD = 100.0
DROP_REWARD = -10.0
VIOLATION_REWARD = -50.0


@dataclass(frozen=True)
class SafetyZone:
    """An axis-aligned box the end effector must never enter.

    :param low: lower corner ``(3,)`` (x, y, z) in metres.
    :param high: upper corner ``(3,)``.
    """

    low: tuple[float, float, float]
    high: tuple[float, float, float]

    def contains(self, point: np.ndarray) -> bool:
        """Whether ``point`` ``(3,)`` lies inside the box (bounds included)."""
        return bool(np.all(point >= np.asarray(self.low)) and np.all(point <= np.asarray(self.high)))


#: Named zones. ``"book"`` is the book's zone (x 0.2-0.8, y 0.2-0.8, z 0-0.5): it contains the block's
#: path and the target, so the task cannot be done safely. ``"default"`` is a box between the robot and
#: the target's side (think of an operator's workstation) that a direct push never crosses but a
#: careless sweep of the arm does. ``"path"`` (x 0.55-0.75, y -0.12-0.1, z 0.03-0.28) lies under the ready pose's
#: tool (0.61, 0, 0.31), across its direct way down to the push start behind the block: a straight move crosses
#: it, a detour over the robot's side (``scripted.PATH_DETOUR``) does not; pushing (z < 0.03) never does.
SAFETY_ZONES: dict[str, SafetyZone] = {
    "book": SafetyZone((0.2, 0.2, 0.0), (0.8, 0.8, 0.5)),
    "default": SafetyZone((0.05, 0.25, 0.0), (0.35, 0.75, 0.5)),
    "path": SafetyZone((0.55, -0.12, 0.03), (0.75, 0.1, 0.28)),
}


def make_safety_zone(zone: str | SafetyZone | Sequence[Sequence[float]] | None) -> SafetyZone | None:
    """Resolve a zone given by name (:data:`SAFETY_ZONES`), as ``(low, high)`` corners, or ``None``."""
    if zone is None or isinstance(zone, SafetyZone):
        return zone
    if isinstance(zone, str):
        if zone not in SAFETY_ZONES:
            raise ValueError(f"unknown safety zone {zone!r}, expected one of {sorted(SAFETY_ZONES)}")
        return SAFETY_ZONES[zone]
    low, high = (tuple(float(v) for v in corner) for corner in zone)
    if len(low) != 3 or len(high) != 3 or any(lo > hi for lo, hi in zip(low, high, strict=True)):
        raise ValueError(f"safety zone must be (low, high) with 3 coordinates each and low <= high, got {zone!r}")
    return SafetyZone(low, high)  # type: ignore[arg-type]


def goal_distance(achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
    """Euclidean distance over the last axis: ``(..., 3), (..., 3) -> (...)``."""
    return np.linalg.norm(np.asarray(achieved_goal) - np.asarray(desired_goal), axis=-1)


def sparse_goal_reward(achieved_goal: np.ndarray, desired_goal: np.ndarray, threshold: float) -> np.ndarray:
    """panda-gym's sparse reward ``-(d > threshold)`` as float32: ``(..., 3), (..., 3) -> (...)``."""
    return -(goal_distance(achieved_goal, desired_goal) > threshold).astype(np.float32)


def dense_goal_reward(achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
    """panda-gym's dense reward ``-d`` as float32: ``(..., 3), (..., 3) -> (...)``."""
    return -goal_distance(achieved_goal, desired_goal).astype(np.float32)


class PushTask:
    """A ``block.urdf`` (or a cube) to push onto a target on the plane, with optional domain randomisation.

    :param sim: the owning simulation.
    :param object: ``"block"`` (the book's ``block.urdf``, a 10 x 1.8 x 1.8 cm stick) or ``"cube"`` (a 4 cm
        cube as panda-gym's push, built with ``createCollisionShape``; same mass and friction as the block).
    :param object_xy: nominal start of the block (book: (0.5, 0)).
    :param object_range: half width of the uniform box around ``object_xy`` the start is drawn from.
    :param target_xy: target on the plane (book: (0.5, 0.5)); its height is the block's resting height.
    :param target_box: if given, ``((x_lo, y_lo), (x_hi, y_hi))``: the target is drawn uniformly in
        this box every episode (goal-conditioned variant) instead of ``target_xy``.
    :param distance_threshold: success when the block's centre is within this distance of the target.
    :param scale_range: ``(lo, hi)`` for a per-episode uniform block scale, ``None`` for scale 1.
    :param mass_range: ``(lo, hi)`` for a per-episode uniform block mass (kg), ``None`` for 0.02 kg.
    :param noise_level: std of the Gaussian noise on the *observed* block position (m).
    :param workspace_radius: the block is "dropped" when its horizontal distance to the robot base
        exceeds this (it is then out of the arm's reach) ...
    :param drop_height: ... or when it falls below this height (through or off the plane).
    """

    def __init__(
        self,
        sim: BulletSim,
        object: str = "block",
        object_xy: Sequence[float] = (0.5, 0.0),
        object_range: float = 0.0,
        target_xy: Sequence[float] = (0.5, 0.5),
        target_box: Sequence[Sequence[float]] | None = None,
        distance_threshold: float = 0.05,
        scale_range: Sequence[float] | None = None,
        mass_range: Sequence[float] | None = None,
        noise_level: float = 0.0,
        workspace_radius: float = 1.0,
        drop_height: float = -0.05,
    ) -> None:
        if object not in OBJECTS:
            raise ValueError(f"object must be one of {OBJECTS}, got {object!r}")
        self.sim = sim
        self.client = sim.client
        self.object = object
        self.object_xy = np.asarray(object_xy, dtype=np.float64)
        self.object_range = float(object_range)
        self.target_xy = np.asarray(target_xy, dtype=np.float64)
        self.target_box = None if target_box is None else np.asarray(target_box, dtype=np.float64)
        self.distance_threshold = float(distance_threshold)
        self.scale_range = None if scale_range is None else (float(scale_range[0]), float(scale_range[1]))
        self.mass_range = None if mass_range is None else (float(mass_range[0]), float(mass_range[1]))
        if noise_level < 0:
            raise ValueError(f"noise_level must be >= 0, got {noise_level}")
        self.noise_level = float(noise_level)
        self.workspace_radius = float(workspace_radius)
        self.drop_height = float(drop_height)
        self.scale = 1.0
        self.mass = BLOCK_MASS
        self.block = self._create_object(self.scale)
        self.target = np.array([*self.target_xy, self.half_height])
        self.marker = sim.create_sphere_marker(0.025, (0.9, 0.2, 0.2, 0.6))

    @property
    def half_height(self) -> float:
        """Height (m) of the object's centre when it rests on the plane at this episode's scale."""
        base = CUBE_SIZE / 2 if self.object == "cube" else BLOCK_HALF_HEIGHT
        return base * self.scale

    def _create_object(self, scale: float) -> int:
        """Load or build the object at ``scale`` on the plane at :attr:`object_xy`; return its body id."""
        if self.object == "block":
            return self.sim.load_urdf("block.urdf", (*self.object_xy, BLOCK_HALF_HEIGHT * scale), scaling=scale)
        size = CUBE_SIZE * scale
        # block.urdf's contact parameters, so that only the shape differs
        return self.sim.create_box(
            size,
            BLOCK_MASS,
            (*self.object_xy, size / 2),
            (0.1, 0.7, 0.1, 1.0),
            lateralFriction=1.0,
            spinningFriction=0.001,
        )

    def reset(self, rng: np.random.Generator) -> None:
        """Draw this episode's block scale, mass, start and target from ``rng`` and place the block.

        Only the block is reloaded, and only when its scale changes (~0.1 ms); everything else is a
        soft reset (teleport).
        """
        scale = 1.0 if self.scale_range is None else float(rng.uniform(*self.scale_range))
        mass = BLOCK_MASS if self.mass_range is None else float(rng.uniform(*self.mass_range))
        start = self.object_xy + rng.uniform(-self.object_range, self.object_range, 2) * (self.object_range > 0)
        target_xy = self.target_xy if self.target_box is None else rng.uniform(self.target_box[0], self.target_box[1])
        if scale != self.scale:
            self.client.removeBody(self.block)
            self.block = self._create_object(scale)
            self.scale = scale
        rest_z = self.half_height
        self.sim.set_base_pose(self.block, (*start, rest_z))
        if mass != self.mass or self.mass_range is not None:
            self.client.changeDynamics(self.block, -1, mass=mass)
            self.mass = mass
        self.target = np.array([*target_xy, rest_z])
        self.sim.set_base_pose(self.marker, self.target)

    # ------------------------------------------------------------ observations
    def object_position(self) -> np.ndarray:
        """True block position ``(3,)``."""
        return self.sim.base_position(self.block)

    def object_velocity(self) -> np.ndarray:
        """True block linear velocity ``(3,)``."""
        return np.asarray(self.client.getBaseVelocity(self.block)[0], dtype=np.float64)

    def observed_object_position(self, rng: np.random.Generator) -> np.ndarray:
        """Block position ``(3,)`` as the sensor reports it (plus N(0, noise_level^2) noise)."""
        pos = self.object_position()
        if self.noise_level > 0:
            pos = pos + rng.normal(0.0, self.noise_level, 3)
        return pos

    # ------------------------------------------------------------------ rules
    def is_success(self, achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
        """Vectorised success test ``(..., 3), (..., 3) -> (...)`` bool."""
        return goal_distance(achieved_goal, desired_goal) < self.distance_threshold

    def is_dropped(self, object_position: np.ndarray) -> bool:
        """The push-task "drop": the block fell below :attr:`drop_height` or left the arm's reach."""
        return bool(
            object_position[2] < self.drop_height
            or np.hypot(object_position[0], object_position[1]) > self.workspace_radius
        )

    def book_reward(self, success: bool, dropped: bool) -> float:
        """The book's reward: +100 on success, -10 on a drop, -1 otherwise."""
        if success:
            return SUCCESS_REWARD
        return DROP_REWARD if dropped else STEP_REWARD

    def dense_reward(self, success: bool, dropped: bool, ee_position: np.ndarray, object_position: np.ndarray) -> float:
        """Shaped reward: the -1 step cost is replaced by ``-(|ee - block| + |block - target|)``.

        Success (+100) and drop (-10) keep the book's values.
        """
        if success:
            return SUCCESS_REWARD
        if dropped:
            return DROP_REWARD
        return -float(np.linalg.norm(ee_position - object_position) + np.linalg.norm(object_position - self.target))

    def sparse_goal_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
        """panda-gym's sparse reward ``-(d > threshold)`` as float32, vectorised over leading axes."""
        return sparse_goal_reward(achieved_goal, desired_goal, self.distance_threshold)

    def dense_goal_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
        """panda-gym's dense reward ``-d`` as float32, vectorised over leading axes."""
        return dense_goal_reward(achieved_goal, desired_goal)
