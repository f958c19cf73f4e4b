"""A small PyBullet wrapper that owns ONE physics client per environment instance.

Every PyBullet call goes through :attr:`BulletSim.client` (a
:class:`pybullet_utils.bullet_client.BulletClient`, which passes its own ``physicsClientId``), so any
number of environments can live in one process without sharing state (the book used the global
module-level client, which made two envs in one process corrupt each other).
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from typing import Any, TypeAlias

import numpy as np
import pybullet
import pybullet_data
from pybullet_utils.bullet_client import BulletClient

#: A vector argument (a position, a quaternion, joint angles): a sequence of floats or an ``(n,)`` array.
Vector: TypeAlias = Sequence[float] | np.ndarray


class BulletSim:
    """One PyBullet physics client, its time step and its camera.

    :param render_mode: ``"human"`` opens a GUI connection, anything else a headless ``DIRECT`` one.
    :param time_step: physics time step in seconds (PyBullet default 1/240 s).
    :param n_substeps: physics steps per environment step (control period = ``time_step * n_substeps``).
    :param gravity: gravity along z in m/s^2.
    :param render_width: width in pixels of ``rgb_array`` frames.
    :param render_height: height in pixels of ``rgb_array`` frames.
    :param solver_residual: if given, Bullet's constraint solver stops its iterations once the residual is below
        this (PyBullet's ``solverResidualThreshold``, default 1e-7).
    """

    def __init__(
        self,
        render_mode: str | None = None,
        time_step: float = 1.0 / 240.0,
        n_substeps: int = 10,
        gravity: float = -9.81,
        render_width: int = 320,
        render_height: int = 240,
        solver_residual: float | None = None,
    ) -> None:
        if n_substeps < 1:
            raise ValueError(f"n_substeps must be >= 1, got {n_substeps}")
        self.render_mode = render_mode
        connection = pybullet.GUI if render_mode == "human" else pybullet.DIRECT
        self.client = BulletClient(connection_mode=connection)
        if render_mode == "human":
            self.client.configureDebugVisualizer(pybullet.COV_ENABLE_GUI, 0)
        self.client.setAdditionalSearchPath(pybullet_data.getDataPath())
        self.time_step = time_step
        self.n_substeps = n_substeps
        self.client.setTimeStep(time_step)
        self.client.setGravity(0.0, 0.0, gravity)
        if solver_residual is not None:
            self.client.setPhysicsEngineParameter(solverResidualThreshold=solver_residual)
        self.render_width = render_width
        self.render_height = render_height
        self._view = self.client.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=[0.35, 0.2, 0.1],
            distance=1.6,
            yaw=50.0,
            pitch=-35.0,
            roll=0.0,
            upAxisIndex=2,
        )
        self._proj = self.client.computeProjectionMatrixFOV(
            fov=60.0, aspect=render_width / render_height, nearVal=0.05, farVal=5.0
        )
        self._closed = False
        # bound once: BulletClient looks every attribute up anew (~1 us per call, 10 physics steps per env step)
        self._step_simulation = self.client.stepSimulation
        self._get_base_pose = self.client.getBasePositionAndOrientation

    @property
    def dt(self) -> float:
        """Duration of one environment step in seconds (``time_step * n_substeps``)."""
        return self.time_step * self.n_substeps

    def load_urdf(
        self,
        file_name: str,
        position: Sequence[float] = (0.0, 0.0, 0.0),
        fixed_base: bool = False,
        scaling: float = 1.0,
    ) -> int:
        """Load a URDF (path relative to ``pybullet_data`` or absolute) and return its body id."""
        return int(
            self.client.loadURDF(file_name, basePosition=list(position), useFixedBase=fixed_base, globalScaling=scaling)
        )

    def create_box(
        self, size: float, mass: float, position: Sequence[float], rgba: Sequence[float], **dynamics: float
    ) -> int:
        """Create a cube of edge ``size`` (m) and ``mass`` (kg) at ``position`` ``(3,)``; ``dynamics`` are
        ``changeDynamics`` keywords (e.g. ``lateralFriction``). Returns its body id."""
        half = [size / 2] * 3
        collision = self.client.createCollisionShape(pybullet.GEOM_BOX, halfExtents=half)
        visual = self.client.createVisualShape(pybullet.GEOM_BOX, halfExtents=half, rgbaColor=list(rgba))
        body = int(
            self.client.createMultiBody(
                baseMass=mass,
                baseCollisionShapeIndex=collision,
                baseVisualShapeIndex=visual,
                basePosition=list(position),
            )
        )
        if dynamics:
            self.client.changeDynamics(body, -1, **dynamics)
        return body

    def create_sphere_marker(self, radius: float, rgba: Sequence[float]) -> int:
        """Create a visual-only (no collision, no mass) sphere, e.g. to show the target, and return its id."""
        visual = self.client.createVisualShape(pybullet.GEOM_SPHERE, radius=radius, rgbaColor=list(rgba))
        return int(self.client.createMultiBody(baseMass=0.0, baseVisualShapeIndex=visual, basePosition=[0, 0, -1]))

    def step(self, n: int | None = None) -> None:
        """Advance the physics by ``n`` time steps (default :attr:`n_substeps`)."""
        step = self._step_simulation
        for _ in range(self.n_substeps if n is None else n):
            step()

    def base_position(self, body: int) -> np.ndarray:
        """Position ``(3,)`` of a body's base frame."""
        return np.array(self._get_base_pose(body)[0])

    def set_base_pose(
        self, body: int, position: Vector, orientation: Vector = (0.0, 0.0, 0.0, 1.0)
    ) -> None:
        """Teleport a body's base and zero its velocity (soft reset, ~10 us)."""
        self.client.resetBasePositionAndOrientation(body, list(position), list(orientation))
        self.client.resetBaseVelocity(body, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])

    def get_base_state(self, body: int) -> tuple[Any, Any, Any, Any]:
        """``(position, orientation, linear velocity, angular velocity)`` of a body's base."""
        pos, orn = self.client.getBasePositionAndOrientation(body)
        lin, ang = self.client.getBaseVelocity(body)
        return pos, orn, lin, ang

    def set_base_state(self, body: int, state: tuple[Any, Any, Any, Any]) -> None:
        """Restore a state returned by :meth:`get_base_state`."""
        pos, orn, lin, ang = state
        self.client.resetBasePositionAndOrientation(body, pos, orn)
        self.client.resetBaseVelocity(body, lin, ang)

    def render(self) -> np.ndarray:
        """Headless TinyRenderer frame of shape ``(render_height, render_width, 3)``, dtype uint8."""
        _, _, rgba, _, _ = self.client.getCameraImage(
            self.render_width,
            self.render_height,
            viewMatrix=self._view,
            projectionMatrix=self._proj,
            renderer=pybullet.ER_TINY_RENDERER,
        )
        frame = np.asarray(rgba, dtype=np.uint8).reshape(self.render_height, self.render_width, 4)
        return np.ascontiguousarray(frame[:, :, :3])

    def close(self) -> None:
        """Disconnect the physics client (idempotent)."""
        if not self._closed:
            self._closed = True
            with contextlib.suppress(pybullet.error):
                self.client.disconnect()
