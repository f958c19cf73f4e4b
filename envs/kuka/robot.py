"""Kuka LBR iiwa 7 (``kuka_iiwa/model.urdf``) with a pusher rod, joint-delta and end-effector-delta control.

The iiwa has 7 revolute joints; the book observes and controls "6 joint angles". We follow it: the
first six joints (base to wrist) are controlled and observed, the seventh (flange rotation about the
tool axis) is held at 0.

The arm has no gripper, and its bare flange cannot push the book's 1.8 cm tall block: the flange's
rounded bottom edge meets the block at about 45 degrees and wedges it into the floor (measured: the
scripted pusher slid over the block in 10 of 10 episodes). We therefore load ``model.urdf`` with one
fixed link appended: a rigid pusher rod (radius 1.5 cm, 10.5 cm long) on the flange's axis. The
end-effector point is the rod's tip; it lies on the seventh joint's axis, so it depends on the first
six joints only.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from collections.abc import Sequence

import numpy as np
import pybullet_data

from sbagents.cache import cache_dir
from sbagents.envs.kuka.sim import BulletSim, Vector

#: Number of controlled (and observed) joints; the 7th joint is held at 0.
N_CONTROLLED = 6
#: Link index of the end effector: the pusher rod appended after link 7, its frame at the rod's tip.
EE_LINK = 7
#: Rod radius and length (m); the rod's tip is 0.145 m from link 7's origin along the tool axis.
PUSHER_RADIUS = 0.015
PUSHER_LENGTH = 0.105
#: Rod friction coefficient (PyBullet multiplies it with the block's 1.0): a high value makes the block
#: pivot about the contact instead of sliding off the rod.
PUSHER_FRICTION = 2.0
#: Quaternion (x, y, z, w) of a tool pointing straight down.
DOWN_ORIENTATION: tuple[float, float, float, float] = (0.0, 1.0, 0.0, 0.0)
#: A well-conditioned arm pose with the tool pointing down, used to seed inverse kinematics when the
#: current pose is singular (the book's all-zero pose is the arm stretched straight up).
READY_POSE: tuple[float, ...] = (0.0, 0.6, 0.0, -1.4, 0.0, 1.1, 0.0)


_PUSHER_XML = f"""
  <joint name="pusher_joint" type="fixed">
    <parent link="lbr_iiwa_link_7"/>
    <child link="pusher_tip"/>
    <origin rpy="0 0 0" xyz="0 0 0.145"/>
  </joint>
  <link name="pusher_tip">
    <contact>
      <lateral_friction value="{PUSHER_FRICTION}"/>
    </contact>
    <inertial>
      <origin rpy="0 0 0" xyz="0 0 {-PUSHER_LENGTH / 2}"/>
      <mass value="0.1"/>
      <inertia ixx="1e-4" ixy="0" ixz="0" iyy="1e-4" iyz="0" izz="1e-5"/>
    </inertial>
    <visual>
      <origin rpy="0 0 0" xyz="0 0 {-PUSHER_LENGTH / 2}"/>
      <geometry><cylinder radius="{PUSHER_RADIUS}" length="{PUSHER_LENGTH}"/></geometry>
      <material name="pusher_grey"><color rgba="0.3 0.3 0.3 1.0"/></material>
    </visual>
    <collision>
      <origin rpy="0 0 0" xyz="0 0 {-PUSHER_LENGTH / 2}"/>
      <geometry><cylinder radius="{PUSHER_RADIUS}" length="{PUSHER_LENGTH}"/></geometry>
    </collision>
  </link>
"""


def kuka_urdf_path(extra_xml: str, name: str) -> str:
    """Path of ``kuka_iiwa/model.urdf`` with ``extra_xml`` (links and joints) appended, written once to the cache.

    Mesh paths are made absolute (into ``pybullet_data``); the file name (``{name}_{hash}.urdf``) carries a
    hash of its content and is written atomically, so concurrent processes can share it.
    """
    kuka_dir = os.path.join(pybullet_data.getDataPath(), "kuka_iiwa")
    with open(os.path.join(kuka_dir, "model.urdf"), encoding="utf-8") as f:
        text = f.read()
    text = text.replace('filename="meshes/', f'filename="{kuka_dir}/meshes/')
    text = text.replace("</robot>", extra_xml + "</robot>")
    digest = hashlib.sha1(text.encode()).hexdigest()[:12]
    folder = str(cache_dir("urdf"))
    path = os.path.join(folder, f"{name}_{digest}.urdf")
    if not os.path.exists(path):
        fd, tmp = tempfile.mkstemp(suffix=".urdf", dir=folder)
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    return path


def pusher_urdf_path() -> str:
    """Path of ``kuka_iiwa/model.urdf`` plus the pusher link, written once to the user's cache folder."""
    return kuka_urdf_path(_PUSHER_XML, "kuka_iiwa_pusher")


class KukaIiwa:
    """The Kuka iiwa arm, loaded once with a fixed base, controlled in position mode.

    :param sim: the owning simulation (one physics client).
    :param base_position: position of the fixed base.
    :param max_force: maximum motor force per joint (N m), the URDF effort limit.
    :param max_velocity: maximum joint speed in position control (rad/s), the URDF velocity limit.
    :param urdf_path: the arm's URDF (default: :func:`pusher_urdf_path`); its first 7 joints are the iiwa's.
    :param ee_link: link index of the end-effector point.
    :param n_controlled: joints driven by control and inverse kinematics (the rest of the 7 are held at 0).
    :param ik_iterations: iterations of PyBullet's inverse kinematics per seed (see :meth:`inverse_kinematics`).
    :param ik_residual: PyBullet's IK stops once the end effector is this close (m) to the target.
    """

    def __init__(
        self,
        sim: BulletSim,
        base_position: Sequence[float] = (0.0, 0.0, 0.0),
        max_force: float = 300.0,
        max_velocity: float = 10.0,
        urdf_path: str | None = None,
        ee_link: int = EE_LINK,
        n_controlled: int = N_CONTROLLED,
        ik_iterations: int = 50,
        ik_residual: float = 1e-4,
    ) -> None:
        self.sim = sim
        self.client = sim.client
        path = pusher_urdf_path() if urdf_path is None else urdf_path
        self.body = sim.load_urdf(path, base_position, fixed_base=True)
        self.ee_link = ee_link
        self.n_controlled = n_controlled
        self.n_joints = 7
        self.joint_indices = list(range(self.n_joints))
        infos = [self.client.getJointInfo(self.body, j) for j in self.joint_indices]
        #: Joint limits ``(7,)`` from the URDF, intersected with the book's [-pi, pi].
        self.lower = np.maximum(np.array([i[8] for i in infos]), -np.pi)
        self.upper = np.minimum(np.array([i[9] for i in infos]), np.pi)
        self.max_force = max_force
        self.max_velocity = max_velocity
        self._targets = np.zeros(self.n_joints)
        self._zero_velocities = [[0.0]] * self.n_joints
        self._forces = [float(max_force)] * self.n_joints
        # the client's bound functions, looked up once: BulletClient resolves every attribute access anew
        # (~1 us each, tens of calls per step)
        self._get_joint_states = self.client.getJointStates
        self._reset_joint_states = self.client.resetJointStatesMultiDof
        self._get_link_state = self.client.getLinkState
        self._motor_control = self.client.setJointMotorControlArray
        self._ik = self.client.calculateInverseKinematics
        self._ready = np.asarray(READY_POSE, dtype=np.float64)
        self._down = list(DOWN_ORIENTATION)
        #: Iterations of PyBullet's damped least-squares IK per seed.
        self.ik_iterations = ik_iterations
        #: PyBullet's IK stops early once the end effector is this close (m) to the target.
        self.ik_residual = ik_residual
        # the last inverse-kinematics solution and its end-effector position: forward kinematics of exactly these
        # angles (a safety-zone check of the commanded pose) needs no second teleport
        self._last_solution: tuple[np.ndarray, np.ndarray] | None = None

    # ------------------------------------------------------------------ state
    def reset(self, joint_angles: Vector) -> None:
        """Teleport the joints to ``joint_angles`` (6 or 7 values) with zero velocity and hold them."""
        q = np.zeros(self.n_joints)
        q[: len(joint_angles)] = joint_angles
        self._teleport(q)
        self.set_joint_targets(q)

    def _teleport(self, angles: np.ndarray, velocities: np.ndarray | None = None) -> None:
        """Reset the joints to ``angles`` ``(7,)`` with ``velocities`` ``(7,)`` (default 0) in one PyBullet call."""
        vel = self._zero_velocities if velocities is None else [[float(v)] for v in velocities]
        self._reset_joint_states(self.body, self.joint_indices, [[float(a)] for a in angles], vel)

    def joint_angles(self) -> np.ndarray:
        """Angles ``(7,)`` of all joints (rad)."""
        return np.array([s[0] for s in self._get_joint_states(self.body, self.joint_indices)])

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Angles and velocities ``(7,)``, ``(7,)`` of all joints."""
        states = self._get_joint_states(self.body, self.joint_indices)
        return np.array([s[0] for s in states]), np.array([s[1] for s in states])

    def set_joint_state(self, angles: np.ndarray, velocities: np.ndarray) -> None:
        """Teleport the joints to ``angles`` with ``velocities`` (used to undo a rejected step)."""
        self._teleport(angles, velocities)

    def ee_position(self) -> np.ndarray:
        """Position ``(3,)`` of the end effector (origin of link ``ee_link``: the pusher tip, or the gripper TCP)."""
        return np.array(self._get_link_state(self.body, self.ee_link, computeForwardKinematics=True)[4])

    def forward_kinematics(self, joint_angles: np.ndarray) -> np.ndarray:
        """End-effector position ``(3,)`` for ``joint_angles`` ``(7,)``; the arm's state is left unchanged."""
        last = self._last_solution
        if last is not None and np.array_equal(last[0], joint_angles):
            return last[1].copy()
        angles, velocities = self.joint_state()
        self._teleport(joint_angles)
        ee = self.ee_position()
        self._teleport(angles, velocities)
        return ee

    # ---------------------------------------------------------------- control
    @property
    def joint_targets(self) -> np.ndarray:
        """The position-control targets ``(7,)`` currently commanded."""
        return self._targets.copy()

    def clip_joints(self, joint_angles: np.ndarray) -> np.ndarray:
        """Clip ``(7,)`` angles to the joint limits (which lie inside the book's [-pi, pi])."""
        return np.minimum(np.maximum(joint_angles, self.lower), self.upper)  # np.clip, without its ~3 us of dispatch

    def set_joint_targets(self, targets: np.ndarray) -> None:
        """Command position-control targets ``(7,)`` for all joints (those past ``n_controlled`` are forced to 0)."""
        targets = self.clip_joints(np.asarray(targets, dtype=np.float64))
        targets[self.n_controlled :] = 0.0
        self._targets = targets
        self._motor_control(
            self.body,
            self.joint_indices,
            self.client.POSITION_CONTROL,
            targetPositions=targets.tolist(),
            forces=self._forces,
        )

    def joint_delta_targets(self, delta: np.ndarray) -> np.ndarray:
        """Targets ``(7,)`` = measured angles + ``delta`` ``(6,)``, clipped to the limits (book control)."""
        q = self.joint_angles()
        q[:N_CONTROLLED] += delta
        q[N_CONTROLLED:] = 0.0
        return self.clip_joints(q)

    def inverse_kinematics(self, position: Vector, tolerance: float = 0.01) -> np.ndarray:
        """Joint targets ``(7,)`` that put the end effector at ``position`` ``(3,)`` pointing down.

        Seeds PyBullet's IK with the current pose and, if that misses ``position`` by more than
        ``tolerance`` (e.g. from the singular all-zero pose), retries from :data:`READY_POSE`. The
        arm's state is left unchanged. Unreachable targets return the closest solution found. The
        solution's end-effector position is remembered: :meth:`forward_kinematics` of exactly these angles (the
        safety-zone check of the commanded pose) returns it without teleporting the arm again.
        """
        angles, velocities = self.joint_state()
        target = [float(x) for x in position]
        best: np.ndarray | None = None
        best_err = np.inf
        for seed in (None, self._ready):
            if seed is not None:  # the current pose needs no reset: IK reads positions, not velocities
                self._teleport(seed)
            q = np.array(
                self._ik(
                    self.body,
                    self.ee_link,
                    target,
                    self._down,
                    maxNumIterations=self.ik_iterations,
                    residualThreshold=self.ik_residual,
                )[: self.n_joints]
            )
            q[self.n_controlled :] = 0.0
            q = self.clip_joints(q)
            self._teleport(q)
            ee = self.ee_position()
            err = float(np.linalg.norm(ee - target))
            if err < best_err:
                best, best_err = q, err
                self._last_solution = (q.copy(), ee)
            if err <= tolerance:
                break
        self._teleport(angles, velocities)
        assert best is not None
        return best
