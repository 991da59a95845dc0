"""A test robot with a gripper, written into a folder: a 7-joint arm with the KUKA iiwa 14's published
link lengths (a kinematic stand-in, not the iiwa model) and two prismatic fingers."""

from __future__ import annotations

from pathlib import Path

#: (axis, offset along z from the previous joint) of joints 1-7 (base to flange: 0.36, 0.42, 0.40, 0.126 m).
_JOINTS = [((0, 0, 1), 0.1575), ((0, 1, 0), 0.2025), ((0, 0, 1), 0.2045), ((0, -1, 0), 0.2155),
           ((0, 0, 1), 0.1845), ((0, 1, 0), 0.2155), ((0, 0, 1), 0.081)]
_LIMITS = [2.96, 2.09, 2.96, 2.09, 2.96, 2.09, 3.05]


def _link(name: str, mass: float = 1.0) -> str:
    i = 0.01 * mass
    return (f'<link name="{name}"><inertial><mass value="{mass}"/>'
            f'<inertia ixx="{i}" iyy="{i}" izz="{i}" ixy="0" ixz="0" iyz="0"/></inertial></link>')


def _urdf(mimic: bool) -> str:
    parts = ['<?xml version="1.0"?>', '<robot name="test_gripper_arm">', _link("link0")]
    for k, ((ax, off), lim) in enumerate(zip(_JOINTS, _LIMITS), start=1):
        parts.append(_link(f"link{k}"))
        parts.append(f'<joint name="joint{k}" type="revolute"><parent link="link{k - 1}"/><child link="link{k}"/>'
                     f'<origin xyz="0 0 {off}"/><axis xyz="{ax[0]} {ax[1]} {ax[2]}"/>'
                     f'<limit lower="{-lim}" upper="{lim}" effort="100" velocity="2"/></joint>')
    parts.append(_link("hand", 0.5))
    parts.append('<joint name="flange" type="fixed"><parent link="link7"/><child link="hand"/><origin xyz="0 0 0.045"/></joint>')
    for side, sign in (("left", 1), ("right", -1)):
        parts.append(_link(f"{side}_finger", 0.1))
        parts.append(f'<joint name="{side}_finger_joint" type="prismatic"><parent link="hand"/><child link="{side}_finger"/>'
                     f'<origin xyz="0 0 0.1"/><axis xyz="0 {sign} 0"/><limit lower="0" upper="0.06" effort="20" velocity="0.2"/>'
                     + ('<mimic joint="left_finger_joint" multiplier="1"/>' if mimic and side == "right" else "") + "</joint>")
    parts.append('<link name="tool0"/>')
    parts.append('<joint name="tool" type="fixed"><parent link="hand"/><child link="tool0"/><origin xyz="0 0 0.15"/></joint>')
    parts.append("</robot>")
    return "\n".join(parts)


def _yaml(mimic: bool) -> str:
    joints = "\n".join(f"  - {{name: joint{k}, position: [{-lim}, {lim}], velocity: 1.5, acceleration: 6.0, effort: 100, actuator: null}}"
                       for k, lim in enumerate(_LIMITS, start=1))
    fingers = ("  joints: [left_finger_joint]\n  open: [0.055]\n  closed: [0.0]\n  actuators: [null]" if mimic else
               "  joints: [left_finger_joint, right_finger_joint]\n  open: [0.055, 0.055]\n  closed: [0.0, 0.0]\n"
               "  actuators: [null, null]")
    return f"""name: test_gripper_arm
model: {{file: test_gripper_arm.urdf}}
base_link: link0
joints:
{joints}
tool_frame: tool0
end_effector:
  type: gripper
  body: hand
{fingers}
home: [0.0, 0.35, 0.0, -1.4, 0.0, 1.0, 0.0]
mapping:
  hand_to_tool_rpy: [0.0, 0.0, -1.5707963267948966]
  ik_seed: [0.0, 0.35, 0.0, -1.4, 0.0, 1.0, 0.0]
"""


def write_gripper_arm(folder: Path, mimic: bool = False) -> Path:
    """Write the URDF and its robot file into ``folder``; returns the robot file's path. ``mimic``: the
    right finger mimics the left one (URDF ``<mimic>``) and the robot file names the left one only."""
    folder = Path(folder)
    (folder / "test_gripper_arm.urdf").write_text(_urdf(mimic))
    path = folder / "test_gripper_arm.yaml"
    path.write_text(_yaml(mimic))
    return path
