"""Kuka LBR iiwa 7 with a parallel-jaw gripper, for :mod:`sbagents.envs.kuka.pick`.

We append a simple parallel jaw to the flange of ``kuka_iiwa/model.urdf`` in a generated URDF (as
:mod:`sbagents.envs.kuka.robot` appends the pusher rod): a box palm on a fixed joint, two box fingers on
prismatic joints along the palm's y axis, coupled by a gear constraint, and a massless tool-centre-point
(TCP) link between the fingers, the end-effector point.

Why not pybullet_data's ``kuka_iiwa/kuka_with_gripper2.sdf`` (the WSG-50 model of PyBullet's
``KukaGymEnv``)? We measured both with a scripted top grasp of a 4 cm, 0.1 kg cube:

- the SDF gripper (14 joints, mesh collision shapes, four finger joints coupled only by their motors, IK
  and finger commands as ``pybullet_envs.bullet.kuka``) lifted 0 of 20 cubes with finger forces of 2.5,
  10 or 30 N: its ~0.3 m long fingers reach below the tip links' frames and knock the cube away on the way
  down, so every grasp needs hand-tuned offsets; raw ``stepSimulation`` rate 7,200-10,900 /s;
- the generated jaw (box fingers, ``FINGER_FRICTION`` 2.0, ``FINGER_FORCE`` 100 N, parallel inner faces)
  lets :class:`~sbagents.envs.kuka.scripted_pick.ScriptedPicker` succeed in 100 of 100 episodes, and
  holds cubes up to 6 cm and 1 kg; raw ``stepSimulation`` rate ~13,200 /s on the same machine.

All seven arm joints are driven: inverse kinematics uses the seventh (flange rotation) to keep the tool
pointing down with a fixed yaw (the jaw closes along the world y axis), so the cube, which rests
axis-aligned, is always grasped across two faces.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pybullet

from sbagents.envs.kuka.robot import KukaIiwa, kuka_urdf_path
from sbagents.envs.kuka.sim import BulletSim

#: Link 7 -> palm centre distance along the tool axis (m); the flange face is ~0.045 m from link 7's origin.
PALM_OFFSET = 0.055
#: Palm box size (x, y, z) in metres.
PALM_SIZE = (0.04, 0.12, 0.02)
#: Finger box size (x, y, z): 2.4 cm wide, 1 cm thick (the closing direction), 6 cm long.
FINGER_SIZE = (0.024, 0.01, 0.06)
#: Stroke of each finger (m): the jaw opens from 0 to ``2 * FINGER_STROKE`` between the inner faces.
FINGER_STROKE = 0.045
#: Largest distance between the fingers' inner faces (m).
MAX_WIDTH = 2 * FINGER_STROKE
#: Finger friction (PyBullet multiplies it with the block's 1.0) and motor force per finger (N).
FINGER_FRICTION = 2.0
FINGER_FORCE = 100.0
#: The TCP, the end-effector point, lies on the tool axis this far above the fingertips (m).
TCP_ABOVE_TIPS = 0.02
#: Link indices in the generated URDF: 0-6 the iiwa, 7 the palm, 8 and 9 the fingers, 10 the TCP.
PALM_LINK = 7
FINGER_JOINTS = (8, 9)
TCP_LINK = 10
#: Distance from the flange's link 7 origin to the TCP along the tool axis (m).
TCP_OFFSET = PALM_OFFSET + PALM_SIZE[2] / 2 + FINGER_SIZE[2] - TCP_ABOVE_TIPS


def _box_link(name: str, size: Sequence[float], mass: float, xyz: Sequence[float], rgba: str, friction: float) -> str:
    box = " ".join(f"{v:g}" for v in size)
    origin = f'<origin rpy="0 0 0" xyz="{xyz[0]:g} {xyz[1]:g} {xyz[2]:g}"/>'
    inertia = mass * max(size) ** 2 / 6
    return f"""
  <link name="{name}">
    <contact><lateral_friction value="{friction}"/><spinning_friction value="0.01"/></contact>
    <inertial>{origin}<mass value="{mass}"/>
      <inertia ixx="{inertia:g}" ixy="0" ixz="0" iyy="{inertia:g}" iyz="0" izz="{inertia:g}"/></inertial>
    <visual>{origin}<geometry><box size="{box}"/></geometry>
      <material name="{name}_colour"><color rgba="{rgba}"/></material></visual>
    <collision>{origin}<geometry><box size="{box}"/></geometry></collision>
  </link>"""


def _gripper_xml() -> str:
    half_finger = FINGER_SIZE[2] / 2
    base = PALM_SIZE[2] / 2  # fingers hang from the palm's lower face
    fingers = ""
    for side, sign in (("left", 1.0), ("right", -1.0)):
        fingers += f"""
  <joint name="gripper_{side}_joint" type="prismatic">
    <parent link="gripper_palm"/>
    <child link="gripper_{side}_finger"/>
    <origin rpy="0 0 0" xyz="0 0 0"/>
    <axis xyz="0 {sign:g} 0"/>
    <limit effort="{FINGER_FORCE}" lower="0" upper="{FINGER_STROKE}" velocity="0.5"/>
  </joint>"""
        fingers += _box_link(
            f"gripper_{side}_finger",
            FINGER_SIZE,
            0.05,
            (0.0, sign * FINGER_SIZE[1] / 2, base + half_finger),
            "0.2 0.2 0.2 1.0",
            FINGER_FRICTION,
        )
    return (
        f"""
  <joint name="gripper_palm_joint" type="fixed">
    <parent link="lbr_iiwa_link_7"/>
    <child link="gripper_palm"/>
    <origin rpy="0 0 0" xyz="0 0 {PALM_OFFSET}"/>
  </joint>"""
        + _box_link("gripper_palm", PALM_SIZE, 0.2, (0.0, 0.0, 0.0), "0.4 0.4 0.4 1.0", 1.0)
        + fingers
        + f"""
  <joint name="gripper_tcp_joint" type="fixed">
    <parent link="gripper_palm"/>
    <child link="gripper_tcp"/>
    <origin rpy="0 0 0" xyz="0 0 {TCP_OFFSET - PALM_OFFSET:g}"/>
  </joint>
  <link name="gripper_tcp">
    <inertial><origin rpy="0 0 0" xyz="0 0 0"/><mass value="0"/>
      <inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>
  </link>
"""
    )


def gripper_urdf_path() -> str:
    """Path of ``kuka_iiwa/model.urdf`` plus the parallel jaw, written once to the user's cache folder."""
    return kuka_urdf_path(_gripper_xml(), "kuka_iiwa_gripper")


class KukaGripper(KukaIiwa):
    """The iiwa with the parallel jaw: all 7 arm joints driven, end effector at the TCP, plus the fingers.

    :param sim: the owning simulation.
    :param base_position: position of the fixed base.
    :param max_force: maximum motor force per arm joint (N m).
    :param finger_force: maximum motor force per finger (N).
    :param arm_collisions: if False (default), the iiwa's base and links 1-7 collide with nothing; only the palm
        and the fingers do. With the tool pointing down and the TCP above ``ee_low`` they never reach the table or
        the cube (the palm is in between), and Bullet's narrow phase on their mesh hulls was ~25% of a step.
    :param ik_iterations: iterations of PyBullet's inverse kinematics per seed (see
        :meth:`~sbagents.envs.kuka.robot.KukaIiwa.inverse_kinematics`).
    :param ik_residual: the IK stops once the TCP is this close (m) to the target. The pusher arm's 50 iterations
        to 0.1 mm cost ~40% of a step here; 30 to 2 mm take ~40% less time and miss a random 5 cm move by 1.9 mm
        (median; 0.4 mm before; panda-gym's IK runs PyBullet's default 20), and the scripted picker keeps its
        success (seeds 100-299: 100% nominal, 99.5% robust).
    """

    def __init__(
        self,
        sim: BulletSim,
        base_position: Sequence[float] = (0.0, 0.0, 0.0),
        max_force: float = 300.0,
        finger_force: float = FINGER_FORCE,
        arm_collisions: bool = False,
        ik_iterations: int = 30,
        ik_residual: float = 2e-3,
    ) -> None:
        super().__init__(
            sim,
            base_position,
            max_force=max_force,
            urdf_path=gripper_urdf_path(),
            ee_link=TCP_LINK,
            n_controlled=7,
            ik_iterations=ik_iterations,
            ik_residual=ik_residual,
        )
        if not arm_collisions:
            for link in range(-1, PALM_LINK):
                self.client.setCollisionFilterGroupMask(self.body, link, 0, 0)
        self.finger_force = float(finger_force)
        self.finger_indices = list(FINGER_JOINTS)
        # a gear constraint couples the fingers, as the linkage of a real parallel jaw: without it both motors
        # saturate against each other and the cube ends up anywhere between them (measured: 2 cm off-centre)
        gear = self.client.createConstraint(
            self.body, FINGER_JOINTS[0], self.body, FINGER_JOINTS[1], pybullet.JOINT_GEAR, [0, 1, 0], [0] * 3, [0] * 3
        )
        self.client.changeConstraint(gear, gearRatio=-1, erp=0.1, maxForce=2 * self.finger_force)
        self._width_target = MAX_WIDTH

    def reset_fingers(self, width: float) -> None:
        """Teleport the fingers to an opening ``width`` (m) and hold it."""
        half = float(np.clip(width, 0.0, MAX_WIDTH)) / 2
        for j in self.finger_indices:
            self.client.resetJointState(self.body, j, half, 0.0)
        self.set_finger_width(width)

    def finger_width(self) -> float:
        """Distance (m) between the fingers' inner faces."""
        states = self._get_joint_states(self.body, self.finger_indices)
        return float(states[0][0] + states[1][0])

    @property
    def finger_target(self) -> float:
        """The commanded opening (m)."""
        return self._width_target

    def set_finger_width(self, width: float) -> None:
        """Command an opening ``width`` (m, clipped to ``[0, MAX_WIDTH]``): each finger goes to half of it."""
        self._width_target = float(np.clip(width, 0.0, MAX_WIDTH))
        half = self._width_target / 2
        self._motor_control(
            self.body,
            self.finger_indices,
            self.client.POSITION_CONTROL,
            targetPositions=[half, half],
            forces=[self.finger_force] * 2,
        )

    def finger_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities ``(2,)``, ``(2,)`` of the two finger joints."""
        states = self._get_joint_states(self.body, self.finger_indices)
        return np.array([s[0] for s in states]), np.array([s[1] for s in states])

    def set_finger_state(self, positions: np.ndarray, velocities: np.ndarray) -> None:
        """Teleport the finger joints (used to undo a rejected step)."""
        for j, p, v in zip(self.finger_indices, positions, velocities, strict=True):
            self.client.resetJointState(self.body, j, float(p), float(v))

    def ee_velocity(self) -> np.ndarray:
        """Linear velocity ``(3,)`` of the TCP in the world frame (m/s)."""
        state = self._get_link_state(self.body, self.ee_link, computeLinkVelocity=True)
        return np.array(state[6])

    def ee_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Position and linear velocity ``(3,)``, ``(3,)`` of the TCP in one PyBullet call (as :meth:`ee_position`
        and :meth:`ee_velocity`)."""
        state = self._get_link_state(self.body, self.ee_link, computeLinkVelocity=True, computeForwardKinematics=True)
        return np.array(state[4]), np.array(state[6])
