"""A robot's kinematics for the embodiment mapping: a Drake MultibodyPlant of the robot alone.

Two variants, both built from a :class:`~besdrake.robot.Robot`:

* :func:`welded_plant` -- the arm welded to the world at its base link, for inverse
  kinematics in the robot's base frame and for time-optimal path parameterisation (Toppra needs
  a plant without free bodies).
* :func:`mounted_plant` -- the arm on a six-DOF *mount chain* (three prismatic joints along
  x, y, z, then revolute yaw, pitch, roll) whose world is the demonstrator's back frame. The six
  mount coordinates are the pose of the robot's base in the synchronization frame: one mathematical
  program can then solve that pose together with the joint configurations of every demonstrated
  pose (see :mod:`besdrake.embodiment.sync_frame`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import PrismaticJoint, RevoluteJoint, SpatialInertia, UnitInertia

from besdrake.robot import Robot

#: Names of the mount coordinates, in the order of the plant's positions.
MOUNT_NAMES = ("mount_x", "mount_y", "mount_z", "mount_yaw", "mount_pitch", "mount_roll")


@dataclass
class KinematicModel:
    """A finalized plant, a context and the frames the embodiment mapping uses."""

    plant: MultibodyPlant
    context: object
    n_mount: int  # 0 or 6 leading positions of the mount chain
    robot: Robot

    @property
    def tool_axis(self) -> np.ndarray:
        """The tool axis (tool frame) that matches the demonstrator's palm normal (robot file ``mapping.tool_axis``)."""
        axis = np.asarray(self.robot.mapping.get("tool_axis", [0.0, 0.0, 1.0]), dtype=float)
        return axis / np.linalg.norm(axis)

    @property
    def ik_seed(self) -> np.ndarray:
        """A joint configuration to start inverse kinematics from (robot file ``mapping.ik_seed``, else home)."""
        return np.asarray(self.robot.mapping.get("ik_seed", self.robot.home), dtype=float)

    @property
    def tcp(self):
        """The robot's tool frame."""
        return self.plant.GetFrameByName(self.robot.tool_frame)

    @property
    def arm_indices(self) -> np.ndarray:
        """Indices of the arm's joints (robot file order) in the plant's positions."""
        return np.array([self.plant.GetJointByName(n).position_start() for n in self.robot.joint_names], dtype=int)

    @property
    def gripper_indices(self) -> np.ndarray:
        """Indices of the gripper's joints in the plant's positions (empty without a gripper)."""
        g = self.robot.end_effector.gripper
        return np.array([self.plant.GetJointByName(n).position_start() for n in (g.joints if g else ())], dtype=int)

    def positions(self, q: np.ndarray, gripper: np.ndarray | None = None) -> np.ndarray:
        """All positions of the welded plant for arm joints ``q``: the gripper's joints at ``gripper``
        (default: the robot file's open position), any other position at the plant's default."""
        if self.n_mount:
            raise ValueError("positions() is for the welded plant")
        if self.plant.num_positions() == self.robot.n_joints:
            return np.asarray(q, dtype=float)
        x = self.plant.GetDefaultPositions().copy()
        x[self.arm_indices] = q
        g = self.robot.end_effector.gripper
        if g is not None:
            x[self.gripper_indices] = g.open if gripper is None else gripper
        return x

    def tcp_pose(self, q: np.ndarray, mount: np.ndarray | None = None) -> RigidTransform:
        """Pose of the tool frame in the plant's world for arm joint positions ``q`` (a gripper stands open)."""
        x = self.positions(q) if self.n_mount == 0 else np.concatenate([mount, q])
        self.plant.SetPositions(self.context, x)
        return self.plant.CalcRelativeTransform(self.context, self.plant.world_frame(), self.tcp)


def welded_plant(robot: Robot) -> KinematicModel:
    """``robot`` welded to the world at its base link."""
    plant = MultibodyPlant(0.0)
    robot.add_model(plant, Parser(plant))
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName(robot.base_link))
    plant.Finalize()
    return KinematicModel(plant, plant.CreateDefaultContext(), 0, robot)


def mounted_plant(robot: Robot) -> KinematicModel:
    """``robot`` on a six-DOF mount chain (x, y, z, yaw, pitch, roll) from the world to its base link."""
    plant = MultibodyPlant(0.0)
    robot.add_model(plant, Parser(plant))
    mount = plant.AddModelInstance("mount")
    inertia = SpatialInertia(1e-3, np.zeros(3), UnitInertia.SolidSphere(0.01))
    axes = ([1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 1], [0, 1, 0], [1, 0, 0])
    parent = plant.world_frame()
    for i, (name, axis) in enumerate(zip(MOUNT_NAMES, axes)):
        body = plant.AddRigidBody(f"{name}_body", mount, inertia)
        joint_type = PrismaticJoint if i < 3 else RevoluteJoint
        plant.AddJoint(joint_type(name, parent, body.body_frame(), np.array(axis, dtype=float)))
        parent = body.body_frame()
    plant.WeldFrames(parent, plant.GetFrameByName(robot.base_link))
    plant.Finalize()
    # Positions must be ordered mount first, then the arm, for the programs built on this plant.
    starts = [plant.GetJointByName(n).position_start() for n in MOUNT_NAMES]
    arm = [plant.GetJointByName(n).position_start() for n in robot.joint_names]
    if starts != list(range(6)) or arm != list(range(6, 6 + robot.n_joints)):
        raise RuntimeError(f"unexpected position order in the mounted plant: mount {starts}, arm {arm}")
    return KinematicModel(plant, plant.CreateDefaultContext(), 6, robot)


def mount_to_transform(mount: np.ndarray) -> RigidTransform:
    """Mount coordinates (x, y, z, yaw, pitch, roll) -> pose of the robot's base in the mount's world.

    The chain applies yaw about z, then pitch about the new y, then roll about the new x.
    """
    x, y, z, yaw, pitch, roll = np.asarray(mount, dtype=float)
    rpy = RollPitchYaw(roll, pitch, yaw)  # R = Rz(yaw) Ry(pitch) Rx(roll)
    return RigidTransform(rpy, [x, y, z])
