"""Generate ``compi.urdf`` (arm + scoop) from the published kinematics and our documented assumptions.

Run ``python3 besdrake/models/compi/generate_urdf.py`` after changing the scoop geometry or a joint limit in
``robot.yaml`` beside it (the robot file is the one source, so that the simulation and the model agree). The
URDF is committed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import yaml

from besdrake.tasks.throwing.scoop import Scoop

OUT = Path(__file__).with_name("compi.urdf")
#: The robot file (read as plain YAML: checking it needs the URDF this script writes).
SPEC = yaml.safe_load(Path(__file__).with_name("robot.yaml").read_text())
SCOOP = Scoop(**SPEC["end_effector"]["params"])
POSITION_LIMITS = [tuple(j["position"]) for j in SPEC["joints"]]
VELOCITY_LIMIT = SPEC["joints"][0]["velocity"]


def f(v) -> str:
    return " ".join(f"{x:.15g}" for x in v)


CONTACT = """      <drake:proximity_properties>
        <drake:point_contact_stiffness value="20000"/>
        <drake:hunt_crossley_dissipation value="5.0"/>
        <drake:relaxation_time value="0.02"/>
        <drake:mu_static value="0.6"/>
        <drake:mu_dynamic value="0.5"/>
      </drake:proximity_properties>
"""

# name, mass (kg), segment length (m), axis the segment runs along, radius (m)
LINKS = [
    ("link1", 2.5, 0.158, "z", 0.06),
    ("link2", 2.0, 0.28, "y", 0.05),
    ("link3", 1.0, 0.0, "z", 0.05),
    ("link4", 1.6, 0.34, "z", 0.045),
    ("link5", 1.2, 0.346, "y", 0.04),
    ("link6", 0.3, 0.05, "z", 0.035),
]
# name, parent, child, xyz, rpy, axis, effort (N m); position limits come from robot.yaml
JOINTS = [
    ("joint1", "linkmount", "link1", (0, 0, 0), (0, 0, 0), (0, 0, 1), 60),
    ("joint2", "link1", "link2", (0, 0, 0.158), (np.pi / 2, 0, 0), (0, 0, -1), 150),
    ("joint3", "link2", "link3", (0, 0.28, 0), (0, 0, 0), (0, 0, -1), 100),
    ("joint4", "link3", "link4", (0, 0, 0), (-np.pi / 2, 0, 0), (0, 0, 1), 40),
    ("joint5", "link4", "link5", (0, 0, 0.34), (np.pi / 2, 0, 0), (0, 0, -1), 40),
    ("joint6", "link5", "link6", (0, 0.346, 0), (-np.pi / 2, 0, 0), (0, 0, 1), 15),
]


def cylinder_inertia(m: float, length: float, r: float, axis: str) -> tuple[float, float, float]:
    ia, it = 0.5 * m * r**2, m * (3 * r**2 + length**2) / 12
    return {"x": (ia, it, it), "y": (it, ia, it), "z": (it, it, ia)}[axis]


def scoop_xml() -> tuple[str, dict]:
    a, h, t = SCOOP.bottom_half_width, SCOOP.lip_height, 0.004
    al = SCOOP.wall_angle
    s_top = h / np.sin(al)
    half_top = SCOOP.top_half_width
    d = np.array([np.cos(al), 0, np.sin(al)])
    n = np.array([-np.sin(al), 0, np.cos(al)])
    c = a * np.array([1, 0, 0]) + s_top / 2 * d - t / 2 * n
    width = 2 * half_top + 0.01
    walls = [
        ("wall_px", (c[0], 0, c[2]), (0, -al, 0), (s_top, width, t)),
        ("wall_nx", (-c[0], 0, c[2]), (0, al, 0), (s_top, width, t)),
        ("wall_py", (0, c[0], c[2]), (al, 0, 0), (width, s_top, t)),
        ("wall_ny", (0, -c[0], c[2]), (-al, 0, 0), (width, s_top, t)),
        ("floor", (0, 0, SCOOP.floor_z - 0.002), (0, 0, 0), (2 * a + 0.01, 2 * a + 0.01, 0.004)),
    ]
    xml = ""
    for name, xyz, rpy, size in walls:
        xml += f"""    <collision name="{name}">
      <origin xyz="{f(xyz)}" rpy="{f(rpy)}"/>
      <geometry><box size="{f(size)}"/></geometry>
{CONTACT}    </collision>
    <visual name="{name}_visual">
      <origin xyz="{f(xyz)}" rpy="{f(rpy)}"/>
      <geometry><box size="{f(size)}"/></geometry>
      <material name="scoop_grey"><color rgba="0.55 0.55 0.6 1"/></material>
    </visual>
"""
    r = 0.035
    crest = SCOOP.rest_height(r)
    info = dict(t=t * 1000, a=a * 1000, h=h * 1000, top=half_top * 1000, c=crest * 1000, lip=(h - (crest - r)) * 1000,
                floor=(crest - r - SCOOP.floor_z) * 1000, ang=np.degrees(al))
    return xml, info


def links_xml() -> str:
    """The arm's links: cylinders along their segments (assumed masses, cylinder inertias), visual only."""
    body = ""
    for name, m, length, ax, rad in LINKS:
        lv = max(length, 0.08)
        com = {"z": (0, 0, length / 2), "y": (0, length / 2, 0)}[ax]
        vis_rpy = {"z": (0, 0, 0), "y": (np.pi / 2, 0, 0)}[ax]
        ixx, iyy, izz = cylinder_inertia(m, lv, rad, ax)
        colour = "0.85 0.85 0.88 1" if name in ("link1", "link4", "link6") else "0.2 0.35 0.6 1"
        body += f"""  <link name="{name}">
    <inertial>
      <origin xyz="{f(com)}" rpy="0 0 0"/>
      <mass value="{m}"/>
      <inertia ixx="{ixx:.6g}" iyy="{iyy:.6g}" izz="{izz:.6g}" ixy="0" ixz="0" iyz="0"/>
    </inertial>
    <visual>
      <origin xyz="{f(com)}" rpy="{f(vis_rpy)}"/>
      <geometry><cylinder radius="{rad}" length="{lv}"/></geometry>
      <material name="compi_{name}"><color rgba="{colour}"/></material>
    </visual>
  </link>
"""
    return body


def joints_xml() -> tuple[str, str]:
    """The revolute joints with their limits, and one position transmission per joint (the actuators)."""
    joints = transmissions = ""
    for (name, parent, child, xyz, rpy, axis, effort), (lo, hi) in zip(JOINTS, POSITION_LIMITS):
        joints += f"""  <joint name="{name}" type="revolute">
    <parent link="{parent}"/>
    <child link="{child}"/>
    <origin xyz="{f(xyz)}" rpy="{f(rpy)}"/>
    <axis xyz="{f(axis)}"/>
    <limit lower="{lo:.15g}" upper="{hi:.15g}" effort="{effort}" velocity="{VELOCITY_LIMIT:g}"/>
  </joint>
"""
        transmissions += f"""  <transmission name="{name}_transmission">
    <type>transmission_interface/SimpleTransmission</type>
    <joint name="{name}"><hardwareInterface>PositionJointInterface</hardwareInterface></joint>
    <actuator name="{name}_motor"><mechanicalReduction>1</mechanicalReduction></actuator>
  </transmission>
"""
    return joints, transmissions


def comment_xml(i: dict) -> str:
    """The model's header comment: sources, assumptions and the scoop's geometry (``i``: scoop_xml's figures)."""
    return f"""<!--
  COMPI (DFKI) with a throwing scoop, for besdrake. GENERATED by generate_urdf.py: edit that script.

  KINEMATICS: from DFKI's published URDF: chain linkmount -> link1 ... link6 -> tcp, offsets,
  rpy and axes as published; at q = 0 the arm points straight up and the tcp is 1.174 m above
  linkmount. Joint position limits: joints 1-5 as used for COMPI (j1 +-pi, j2 [-1.8, 2.09],
  j3 +-2.3, j4 +-pi, j5 +-2.0); joint6 +-pi is our choice. Motor speed limit 3.14 rad/s.

  ASSUMPTIONS (not published; chosen to be plausible for a ~9 kg lightweight arm):
  * Link masses (kg): link1 2.5, link2 2.0, link3 1.0 (elbow drive), link4 1.6, link5 1.2,
    link6 0.3, scoop 0.15, linkmount 2.0 (welded, irrelevant). Each link is a solid cylinder along
    its segment (radius 0.035-0.06 m, inertia of that cylinder, centre of mass at the segment midpoint).
  * Actuator effort limits (N m): 60, 150, 100, 40, 40, 15: enough for the throws of the learning
    platform; Drake saturates the joint PD servos there.
  * Links have visual geometry only; only the scoop collides (the ball never touches the links during
    a throw; arm-ground contact is not modelled).

  SCOOP (body "scoop", welded at the tcp; its +z is the opening direction): a square funnel of four
  thin boxes ({i['t']:.0f} mm thick) inclined at {i['ang']:.0f} deg. Bottom half-width {i['a']:.0f} mm, lip
  top {i['h']:.1f} mm above the scoop origin, top half-width {i['top']:.0f} mm. A ball of radius 35 mm rests
  on the four walls with its centre {i['c']:.1f} mm above the scoop origin, centred by the funnel (no
  rattling). The lip rises {i['lip']:.1f} mm above the ball's lowest point (the ball radius is 35 mm):
  the ball cannot roll out while the scoop accelerates; it leaves over the lip when the scoop
  decelerates, which keeps the release (and the landing point) a smooth function of the motion.
  Scoop contact: stiffness 20000 N/m (aluminium, much stiffer than the foam ball, so the ball's
  compliance dominates), friction 0.6/0.5 like the ball's, so the combined ball-scoop friction is
  0.6/0.5. A floor plate {i['floor']:.1f} mm below the resting ball's lowest point is a safety stop only.
-->
"""


def main() -> Path:
    """Write compi.urdf beside this script from the tables above."""
    body = links_xml()
    joints, transmissions = joints_xml()
    scoop, i = scoop_xml()
    urdf = f"""<?xml version="1.0"?>
{comment_xml(i)}<robot name="compi" xmlns:drake="http://drake.mit.edu">
  <link name="linkmount">
    <inertial>
      <origin xyz="0 0 -0.03" rpy="0 0 0"/>
      <mass value="2.0"/>
      <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/>
    </inertial>
    <visual>
      <origin xyz="0 0 -0.03" rpy="0 0 0"/>
      <geometry><cylinder radius="0.08" length="0.06"/></geometry>
      <material name="mount_dark"><color rgba="0.25 0.25 0.25 1"/></material>
    </visual>
  </link>
{body}  <link name="tcp">
    <inertial>
      <origin xyz="0 0 0" rpy="0 0 0"/>
      <mass value="0.01"/>
      <inertia ixx="1e-6" iyy="1e-6" izz="1e-6" ixy="0" ixz="0" iyz="0"/>
    </inertial>
  </link>
  <link name="scoop">
    <inertial>
      <origin xyz="0 0 0.02" rpy="0 0 0"/>
      <mass value="0.15"/>
      <inertia ixx="2e-4" iyy="2e-4" izz="3e-4" ixy="0" ixz="0" iyz="0"/>
    </inertial>
{scoop}  </link>
{joints}  <joint name="tcp_joint" type="fixed">
    <parent link="link6"/>
    <child link="tcp"/>
    <origin xyz="0 0 0.05" rpy="0 0 0"/>
  </joint>
  <joint name="scoop_joint" type="fixed">
    <parent link="tcp"/>
    <child link="scoop"/>
    <origin xyz="0 0 0" rpy="0 0 0"/>
  </joint>
{transmissions}</robot>
"""
    OUT.write_text(urdf)
    return OUT


if __name__ == "__main__":
    print(main())
