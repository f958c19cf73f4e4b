"""The pick-and-place task of :mod:`sbagents.envs.kuka.pick`: a cube to lift onto a 3-D target, drawn as panda-gym's
``PickAndPlace`` draws it, with chapter 6's optional randomisation (cube scale and mass, observation noise).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sbagents.envs.kuka.sim import BulletSim
from sbagents.envs.kuka.tasks import goal_distance

#: Edge of the cube at scale 1 (m), as panda-gym's 4 cm.
BLOCK_SIZE = 0.04
#: Mass of the cube at scale 1 (kg).
BLOCK_MASS = 0.1

class PickTask:
    """A cube to lift onto a 3-D target (panda-gym's PickAndPlace), with optional domain randomisation.

    :param sim: the owning simulation.
    :param object_xy: centre of the square the cube's start and the target's (x, y) are drawn from.
    :param object_range: half width (m) of the cube's start square (panda-gym: 0.15, a 0.3 m square).
    :param target_range: half width (m) of the target's (x, y) square.
    :param target_height: ``(lo, hi)`` of the target's height above the resting cube (panda-gym: (0, 0.2)).
    :param table_probability: probability that the target lies on the table (height 0; panda-gym: 0.3).
    :param distance_threshold: success when the cube's centre is within this distance of the target.
    :param scale_range: ``(lo, hi)`` of a per-episode uniform cube scale, ``None`` for 1 (4 cm).
    :param mass_range: ``(lo, hi)`` of a per-episode uniform cube mass (kg), ``None`` for 0.1 kg.
    :param noise_level: std (m) of the Gaussian noise on the *observed* cube position.
    """

    def __init__(
        self,
        sim: BulletSim,
        object_xy: Sequence[float] = (0.6, 0.0),
        object_range: float = 0.15,
        target_range: float = 0.15,
        target_height: Sequence[float] = (0.0, 0.2),
        table_probability: float = 0.3,
        distance_threshold: float = 0.05,
        scale_range: Sequence[float] | None = None,
        mass_range: Sequence[float] | None = None,
        noise_level: float = 0.0,
    ) -> None:
        if noise_level < 0:
            raise ValueError(f"noise_level must be >= 0, got {noise_level}")
        if not 0.0 <= table_probability <= 1.0:
            raise ValueError(f"table_probability must be in [0, 1], got {table_probability}")
        self.sim = sim
        self.client = sim.client
        self.object_xy = np.asarray(object_xy, dtype=np.float64)
        self.object_range = float(object_range)
        self.target_range = float(target_range)
        self.target_height = (float(target_height[0]), float(target_height[1]))
        self.table_probability = float(table_probability)
        self.distance_threshold = float(distance_threshold)
        self.scale_range = None if scale_range is None else (float(scale_range[0]), float(scale_range[1]))
        self.mass_range = None if mass_range is None else (float(mass_range[0]), float(mass_range[1]))
        self.noise_level = float(noise_level)
        self.scale = 1.0
        self.mass = BLOCK_MASS
        self.block = self._create_block(self.scale, self.mass)
        self.target = np.array([*self.object_xy, BLOCK_SIZE / 2])
        self.marker = sim.create_sphere_marker(0.02, (0.2, 0.8, 0.2, 0.5))

    def _create_block(self, scale: float, mass: float) -> int:
        size = BLOCK_SIZE * scale
        return self.sim.create_box(
            size,
            mass,
            (*self.object_xy, size / 2),
            (0.1, 0.4, 0.9, 1.0),
            lateralFriction=1.0,
            spinningFriction=0.001,
            rollingFriction=0.0,
        )

    @property
    def half_size(self) -> float:
        """Half the cube's edge (m) this episode: the height of its centre when it rests on the table."""
        return BLOCK_SIZE * self.scale / 2

    def reset(self, rng: np.random.Generator) -> None:
        """Draw the cube's scale, mass and start and the target from ``rng``; place the cube (soft reset).

        The cube is recreated only when its scale changes (~0.1 ms); otherwise everything is teleported.
        """
        scale = 1.0 if self.scale_range is None else float(rng.uniform(*self.scale_range))
        mass = BLOCK_MASS if self.mass_range is None else float(rng.uniform(*self.mass_range))
        start = self.object_xy + rng.uniform(-self.object_range, self.object_range, 2)
        target_xy = self.object_xy + rng.uniform(-self.target_range, self.target_range, 2)
        height = float(rng.uniform(*self.target_height))
        if rng.random() < self.table_probability:
            height = 0.0
        if scale != self.scale:
            self.client.removeBody(self.block)
            self.block = self._create_block(scale, mass)
            self.scale = scale
        elif mass != self.mass:
            self.client.changeDynamics(self.block, -1, mass=mass)
        self.mass = mass
        self.sim.set_base_pose(self.block, (*start, self.half_size))
        self.target = np.array([*target_xy, self.half_size + height])
        self.sim.set_base_pose(self.marker, self.target)

    # ------------------------------------------------------------ observations
    def object_position(self) -> np.ndarray:
        """True cube position ``(3,)``."""
        return self.sim.base_position(self.block)

    def observed_object_position(self, rng: np.random.Generator) -> np.ndarray:
        """Cube position ``(3,)`` as the sensor reports it (plus N(0, noise_level^2) noise)."""
        pos = self.object_position()
        if self.noise_level > 0:
            pos = pos + rng.normal(0.0, self.noise_level, 3)
        return pos

    def object_state(self) -> np.ndarray:
        """True orientation (Euler angles, rad), linear velocity and angular velocity, ``(9,)``."""
        _, orn, lin, ang = self.sim.get_base_state(self.block)
        return np.concatenate([self.client.getEulerFromQuaternion(orn), lin, ang])

    # ------------------------------------------------------------------ rules
    def is_success(self, achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
        """Vectorised success test ``(..., 3), (..., 3) -> (...)`` bool."""
        return goal_distance(achieved_goal, desired_goal) < self.distance_threshold
