"""Generate ``iiwa14.urdf`` (KUKA LBR iiwa 14 R820 + a WSG-50-like parallel gripper) from published data.

Run ``python3 besdrake/models/iiwa14/generate_urdf.py`` after changing a joint limit, the gripper or the pad
friction in ``robot.yaml`` beside it (the robot file is the one source). The URDF is committed.

Frames: every link frame is parallel to the base frame when all joints are at 0 (the arm points straight up);
each joint's origin lies on its axis (A1, A3, A5, A7 along +z; A2 +y, A4 -y, A6 +y), so the link offsets below are
plain heights. Masses and centres of mass are published figures (see ``robot.yaml`` ``sources``); inertias are
solid cylinders (our estimate).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

OUT = Path(__file__).with_name("iiwa14.urdf")
#: The robot file (read as plain YAML: checking it needs the URDF this script writes).
SPEC = yaml.safe_load(Path(__file__).with_name("robot.yaml").read_text())
PAD_MU = float(SPEC["end_effector"]["params"]["pad_friction"])
FINGER_STROKE = float(SPEC["end_effector"]["open"][0])
GRIP_EFFORT = float(SPEC["end_effector"]["effort"][0])   # N on the coupled pair: each pad pushes half of it

# Height (m) of each joint's origin above the base at q = 0 (KUKA data sheet: A2 at 0.36, A4 at 0.78, A6 at 1.18,
# flange 0.126 beyond A6), its axis, and the link it moves.
JOINT_HEIGHTS = [0.1575, 0.36, 0.5645, 0.78, 0.9645, 1.18, 1.261]
AXES = [(0, 0, 1), (0, 1, 0), (0, 0, 1), (0, -1, 0), (0, 0, 1), (0, 1, 0), (0, 0, 1)]
FLANGE_HEIGHT = 1.306
# Published masses (kg) and centres of mass (m, base frame at q = 0) of links 1-7.
MASSES = [6.404, 7.89, 2.54, 4.82, 1.76, 2.50, 0.42]
COMS = [(0, -0.014, 0.2545), (0, 0.003, 0.424), (0, 0.019, 0.6905), (0, -0.009, 0.866),
        (0, -0.013, 1.0585), (0, -0.002, 1.196), (0, 0, 1.2706)]
# Collision capsules per link: radius (m), z from / to (m, link frame); cylinder inertia uses the same radius.
CAPSULES = [(0.075, 0.02, 0.19), (0.075, 0.0, 0.20), (0.065, 0.02, 0.20), (0.065, 0.0, 0.18),
            (0.06, 0.02, 0.19), (0.06, -0.02, 0.06), (0.045, 0.0, 0.04)]
# Gripper: housing box (m, x y z; z along the tool axis from the flange), masses (kg), finger geometry.
HOUSING = (0.05, 0.146, 0.072)
HOUSING_MASS = 1.2
FINGER_MASS = 0.1
FINGER = (0.02, 0.018, 0.09)   # x, y (thickness), z (length) of each finger
PAD_R = 0.004                  # pad spheres' radius; each finger has 2 x 2 of them on its inner face
PAD_Z = (0.06, 0.08)           # pad heights along the finger (m from the finger's root)
PAD_X = (-0.007, 0.007)
TOOL_Z = HOUSING[2] + 0.5 * (PAD_Z[0] + PAD_Z[1])   # tool frame: between the pads, from the flange


def f(v) -> str:
    return " ".join(f"{x:.10g}" for x in v)


def contact(mu: float, stiffness: float = 1e5, dissipation: float = 1.0) -> str:
    return f"""      <drake:proximity_properties>
        <drake:point_contact_stiffness value="{stiffness:g}"/>
        <drake:hunt_crossley_dissipation value="{dissipation:g}"/>
        <drake:relaxation_time value="0.01"/>
        <drake:mu_static value="{mu:g}"/>
        <drake:mu_dynamic value="{mu:g}"/>
      </drake:proximity_properties>
"""


def inertial(mass: float, com, ixx: float, iyy: float, izz: float) -> str:
    return f"""    <inertial>
      <origin xyz="{f(com)}" rpy="0 0 0"/>
      <mass value="{mass:g}"/>
      <inertia ixx="{ixx:.6g}" iyy="{iyy:.6g}" izz="{izz:.6g}" ixy="0" ixz="0" iyz="0"/>
    </inertial>
"""


def cylinder_inertia(m: float, r: float, length: float) -> tuple[float, float, float]:
    it = m * (3 * r * r + length * length) / 12
    return it, it, 0.5 * m * r * r


def capsule(name: str, r: float, z0: float, z1: float, colour: str) -> str:
    length, zc = z1 - z0, 0.5 * (z0 + z1)
    return f"""    <visual name="{name}_visual">
      <origin xyz="0 0 {zc:.6g}"/>
      <geometry><capsule radius="{r}" length="{length:.6g}"/></geometry>
      <material name="{name}_colour"><color rgba="{colour}"/></material>
    </visual>
    <collision name="{name}_collision">
      <origin xyz="0 0 {zc:.6g}"/>
      <geometry><capsule radius="{r}" length="{length:.6g}"/></geometry>
{contact(0.5)}    </collision>
"""


def arm_links() -> str:
    xml = f"""  <link name="iiwa_link_0">
{inertial(5.0, (-0.01, 0, 0.07), 0.05, 0.06, 0.03)}    <visual>
      <origin xyz="0 0 0.075"/>
      <geometry><cylinder radius="0.11" length="0.15"/></geometry>
      <material name="base_grey"><color rgba="0.3 0.3 0.3 1"/></material>
    </visual>
  </link>
"""
    for i, (m, com, (r, z0, z1), h) in enumerate(zip(MASSES, COMS, CAPSULES, JOINT_HEIGHTS), start=1):
        local = np.array(com) - (0, 0, h)
        ixx, iyy, izz = cylinder_inertia(m, r, max(z1 - z0, 0.08) + 2 * r)
        colour = "1 0.45 0.05 1" if i in (2, 4, 6) else "0.85 0.85 0.85 1"
        xml += f"""  <link name="iiwa_link_{i}">
{inertial(m, local, ixx, iyy, izz)}{capsule(f"iiwa_link_{i}", r, z0, z1, colour)}  </link>
"""
    return xml


def arm_joints() -> str:
    xml = ""
    heights = [0.0] + JOINT_HEIGHTS
    for i, (spec, axis) in enumerate(zip(SPEC["joints"], AXES), start=1):
        lo, hi = spec["position"]
        xml += f"""  <joint name="{spec['name']}" type="revolute">
    <parent link="iiwa_link_{i - 1}"/>
    <child link="iiwa_link_{i}"/>
    <origin xyz="0 0 {heights[i] - heights[i - 1]:.6g}" rpy="0 0 0"/>
    <axis xyz="{f(axis)}"/>
    <limit lower="{lo:.15g}" upper="{hi:.15g}" effort="{spec['effort']:g}" velocity="{spec['velocity']:.15g}"/>
  </joint>
"""
    return xml


def finger(side: str, sign: int) -> str:
    """A finger link: its frame on the gripper axis at the finger root; the pads' inner points at y = 0."""
    fx, fy, fz = FINGER
    body_y = sign * (2 * PAD_R - 0.001 + fy / 2)  # the finger body 1 mm behind the pads' inner points
    pads = ""
    for k, (z, x) in enumerate((z, x) for z in PAD_Z for x in PAD_X):
        pads += f"""    <collision name="{side}_pad_{k}">
      <origin xyz="{x:g} {sign * PAD_R:g} {z:g}"/>
      <geometry><sphere radius="{PAD_R}"/></geometry>
{contact(PAD_MU)}    </collision>
"""
    ixx, iyy, izz = (FINGER_MASS * (fy**2 + fz**2) / 12, FINGER_MASS * (fx**2 + fz**2) / 12, FINGER_MASS * (fx**2 + fy**2) / 12)
    return f"""  <link name="{side}_finger">
{inertial(FINGER_MASS, (0, body_y, fz / 2), ixx, iyy, izz)}    <visual>
      <origin xyz="0 {body_y:.6g} {fz / 2:g}"/>
      <geometry><box size="{f(FINGER)}"/></geometry>
      <material name="finger_dark"><color rgba="0.15 0.15 0.15 1"/></material>
    </visual>
    <collision name="{side}_finger_body">
      <origin xyz="0 {body_y:.6g} {fz / 2:g}"/>
      <geometry><box size="{f(FINGER)}"/></geometry>
{contact(0.5)}    </collision>
{pads}  </link>
"""


def gripper() -> str:
    hx, hy, hz = HOUSING
    xml = f"""  <link name="gripper_base">
{inertial(HOUSING_MASS, (0, 0, hz / 2), HOUSING_MASS * (hy**2 + hz**2) / 12, HOUSING_MASS * (hx**2 + hz**2) / 12, HOUSING_MASS * (hx**2 + hy**2) / 12)}    <visual>
      <origin xyz="0 0 {hz / 2:g}"/>
      <geometry><box size="{f(HOUSING)}"/></geometry>
      <material name="housing_grey"><color rgba="0.6 0.6 0.65 1"/></material>
    </visual>
    <collision name="housing">
      <origin xyz="0 0 {hz / 2:g}"/>
      <geometry><box size="{f(HOUSING)}"/></geometry>
{contact(0.5)}    </collision>
  </link>
  <link name="tool0"/>
{finger("left", 1)}{finger("right", -1)}  <joint name="gripper_mount" type="fixed">
    <parent link="iiwa_link_7"/>
    <child link="gripper_base"/>
    <origin xyz="0 0 {FLANGE_HEIGHT - JOINT_HEIGHTS[-1]:.6g}"/>
  </joint>
  <joint name="tool0_joint" type="fixed">
    <parent link="gripper_base"/>
    <child link="tool0"/>
    <origin xyz="0 0 {TOOL_Z:.6g}"/>
  </joint>
"""
    for side, axis in (("left", (0, 1, 0)), ("right", (0, -1, 0))):
        mimic = '    <mimic joint="left_finger_joint" multiplier="1" offset="0"/>\n' if side == "right" else ""
        xml += f"""  <joint name="{side}_finger_joint" type="prismatic">
    <parent link="gripper_base"/>
    <child link="{side}_finger"/>
    <origin xyz="0 0 {hz:g}"/>
    <axis xyz="{f(axis)}"/>
    <limit lower="0" upper="{FINGER_STROKE:g}" effort="{GRIP_EFFORT:g}" velocity="0.5"/>
{mimic}  </joint>
"""
    return xml


def transmissions() -> str:
    names = [(j["name"], f"{j['name']}_motor") for j in SPEC["joints"]]
    names += list(zip(SPEC["end_effector"]["joints"], SPEC["end_effector"]["actuators"]))
    return "".join(f"""  <transmission name="{joint}_transmission">
    <type>transmission_interface/SimpleTransmission</type>
    <joint name="{joint}"><hardwareInterface>PositionJointInterface</hardwareInterface></joint>
    <actuator name="{motor}"><mechanicalReduction>1</mechanicalReduction></actuator>
  </transmission>
""" for joint, motor in names)


HEADER = """<?xml version="1.0"?>
<!--
  KUKA LBR iiwa 14 R820 with a WSG-50-like parallel gripper, for besdrake. GENERATED by generate_urdf.py: edit that
  script (or robot.yaml beside it) and rerun it.

  KINEMATICS (KUKA data sheet): joint heights above the base at q = 0: A1 0.1575, A2 0.36, A3 0.5645, A4 0.78,
  A5 0.9645, A6 1.18, A7 1.261, flange 1.306 m. Every link frame is parallel to the base frame at q = 0.
  LIMITS: robot.yaml (KUKA data sheet). MASSES / CENTRES OF MASS: published figures (robot.yaml sources);
  INERTIAS: solid cylinders of the collision capsules' radii (estimate).
  COLLISION: one capsule per link; the gripper housing a box; each finger a box with 2 x 2 sphere pads
  (r = {pad_r} m, friction {mu}) on its inner face, so that a grasped box touches four points per finger.
  GRIPPER: prismatic fingers along +y (left) and -y (right), 0 to {stroke} m each (the value is the distance of the
  pads' inner points from the gripper axis), coupled like a WSG 50's belt drive: the right finger mimics the left
  (a coupler constraint in Drake's SAP), one actuator drives the pair, so each pad squeezes with half its effort.
  tool0 lies between the pads, {tool_z} m from the flange.
-->
<robot name="iiwa14" xmlns:drake="http://drake.mit.edu">
"""


def main(out: Path = OUT) -> Path:
    """Write the URDF to ``out`` (default: ``iiwa14.urdf`` beside this script)."""
    urdf = HEADER.format(pad_r=PAD_R, mu=PAD_MU, stroke=FINGER_STROKE, tool_z=f"{TOOL_Z:.4g}")
    urdf += arm_links() + arm_joints() + gripper() + transmissions() + "</robot>\n"
    out.write_text(urdf)
    return out


if __name__ == "__main__":
    print(main())
