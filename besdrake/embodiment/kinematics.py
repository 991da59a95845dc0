"""COMPI's kinematics for the embodiment mapping: a Drake MultibodyPlant without the ball.

Two variants:

* :func:`compi_plant` -- the arm welded to the world at its base (``linkmount``), for inverse
  kinematics in the robot's base frame and for time-optimal path parameterisation (Toppra needs
  a plant without free bodies).
* :func:`mounted_compi_plant` -- the arm on a six-DOF *mount chain* (three prismatic joints along
  x, y, z, then revolute yaw, pitch, roll) whose world is the demonstrator's back frame. The six
  mount coordinates are the pose of COMPI's base in the synchronization frame: one mathematical
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

from besdrake import robot

#: Names of the mount coordinates, in the order of the plant's positions.
MOUNT_NAMES = ("mount_x", "mount_y", "mount_z", "mount_yaw", "mount_pitch", "mount_roll")


@dataclass
class KinematicModel:
    """A finalized plant, a context and the frames the embodiment mapping uses."""

    plant: MultibodyPlant
    context: object
    n_mount: int  # 0 or 6 leading positions of the mount chain

    @property
    def tcp(self):
        return self.plant.GetFrameByName(robot.TCP_FRAME)

    def tcp_pose(self, q: np.ndarray, mount: np.ndarray | None = None) -> RigidTransform:
        """Pose of the tcp (= scoop frame) in the plant's world for joint positions ``q``."""
        x = q if self.n_mount == 0 else np.concatenate([mount, q])
        self.plant.SetPositions(self.context, x)
        return self.plant.CalcRelativeTransform(self.context, self.plant.world_frame(), self.tcp)


def _parse_compi(plant: MultibodyPlant):
    parser = Parser(plant)
    robot.add_package(parser.package_map())
    (instance,) = parser.AddModels(str(robot.compi_model_path()))
    return instance


def compi_plant() -> KinematicModel:
    """COMPI welded to the world at its base frame."""
    plant = MultibodyPlant(0.0)
    _parse_compi(plant)
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName(robot.BASE_LINK))
    plant.Finalize()
    return KinematicModel(plant, plant.CreateDefaultContext(), 0)


def mounted_compi_plant() -> KinematicModel:
    """COMPI on a six-DOF mount chain (x, y, z, yaw, pitch, roll) from the world to its base."""
    plant = MultibodyPlant(0.0)
    _parse_compi(plant)
    mount = plant.AddModelInstance("mount")
    inertia = SpatialInertia(1e-3, np.zeros(3), UnitInertia.SolidSphere(0.01))
    axes = ([1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 1], [0, 1, 0], [1, 0, 0])
    parent = plant.world_frame()
    for i, (name, axis) in enumerate(zip(MOUNT_NAMES, axes)):
        body = plant.AddRigidBody(f"{name}_body", mount, inertia)
        joint_type = PrismaticJoint if i < 3 else RevoluteJoint
        plant.AddJoint(joint_type(name, parent, body.body_frame(), np.array(axis, dtype=float)))
        parent = body.body_frame()
    plant.WeldFrames(parent, plant.GetFrameByName(robot.BASE_LINK))
    plant.Finalize()
    # Positions must be ordered mount first, then the arm, for the programs built on this plant.
    starts = [plant.GetJointByName(n).position_start() for n in MOUNT_NAMES]
    arm = [plant.GetJointByName(n).position_start() for n in robot.JOINT_NAMES]
    if starts != list(range(6)) or arm != list(range(6, 12)):
        raise RuntimeError(f"unexpected position order in the mounted plant: mount {starts}, arm {arm}")
    return KinematicModel(plant, plant.CreateDefaultContext(), 6)


def mount_to_transform(mount: np.ndarray) -> RigidTransform:
    """Mount coordinates (x, y, z, yaw, pitch, roll) -> pose of COMPI's base in the mount's world.

    The chain applies yaw about z, then pitch about the new y, then roll about the new x.
    """
    x, y, z, yaw, pitch, roll = np.asarray(mount, dtype=float)
    rpy = RollPitchYaw(roll, pitch, yaw)  # R = Rz(yaw) Ry(pitch) Rx(roll)
    return RigidTransform(rpy, [x, y, z])
