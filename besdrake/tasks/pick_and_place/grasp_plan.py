"""A grasp skill on a robot: tool poses in the robot's base frame, pose IK, temporal scaling, the plan.

:func:`grasp_plan` takes a :class:`~besdrake.tasks.pick_and_place.imitation.GraspSkill` (or the
demonstration it is fitted from) and a robot file:

1. the skill's goals are set to the scene's box places (:meth:`GraspSkill.adapted`);
2. its rollout (grasp point poses in the task frame) is mapped into the robot's base frame by the task
   frame's pose in the scene ``X_world_task`` (where the scene puts the box on the shelf, the task x axis
   towards the table place) and the robot's ``X_world_base``; the tool's orientation is the hand
   plate's times the robot file's **``mapping.hand_to_tool_rpy``** (roll, pitch, yaw in rad, default 0:
   the tool frame's axes expressed in the hand plate frame, ``R_hand_tool = RollPitchYaw(rpy)``; the hand
   plate frame has y from the right to the left hand marker and z towards the top marker);
3. full-pose IK (:func:`besdrake.embodiment.pose_ik.pose_ik_trajectory`) every ``ik_dt`` s, the gripper
   held open;
4. uniform temporal scaling to the robot's velocity and acceleration limits
   (:func:`besdrake.embodiment.scaling.temporal_scaling`, no minimum duration);
5. a :class:`~besdrake.plan.MotionPlan` through the IK solutions at the scaled times, with the gripper
   command ``meta["gripper"] = {"t": [...], "width": [...]}`` (the distance between the pads, m,
   linearly interpolated: open, closing over ``close_duration`` from the skill's close time, held,
   opening from its open time; times scaled with the arm's). Widths: each gripper joint moves half
   the width, so open = 2 x the mean of the robot file's ``end_effector.open`` positions, closed
   likewise. A robot without a gripper gets no command (a note says so).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix

from besdrake.embodiment.kinematics import KinematicModel, welded_plant
from besdrake.embodiment.pose_ik import PoseIKOptions, PoseIKTrajectory, pose_ik_trajectory
from besdrake.embodiment.scaling import TemporalScaling, temporal_scaling
from besdrake.plan import MotionPlan
from besdrake.robot import Robot, load_robot
from besdrake.tasks.pick_and_place.imitation import DEFAULT_CLOSE_DURATION, GraspSkill, rotation_matrices
from besdrake.tasks.pick_and_place.task_frame import task_frame

#: Robot file key: the tool frame's orientation in the hand plate frame (roll, pitch, yaw; rad).
HAND_TO_TOOL_KEY = "hand_to_tool_rpy"


@dataclass
class GraspPlan:
    """A grasp skill on a robot: the plan and how it was made. ``target_*``: the tool poses IK was asked
    for (robot base frame) at ``ik.t`` (DMP time, before scaling); ``plan`` times are ``scaling.factor``
    times longer."""

    plan: MotionPlan
    skill: GraspSkill
    ik: PoseIKTrajectory
    scaling: TemporalScaling
    target_position: np.ndarray
    target_orientation: np.ndarray
    X_base_task: RigidTransform
    notes: list[str] = field(default_factory=list)

    @property
    def unreachable(self) -> int:
        return int((~self.ik.reachable).sum())

    def summary(self) -> dict:
        """JSON-ready figures (SI units)."""
        return {"source": self.skill.source, "duration_s": self.plan.duration, "time_scale": self.scaling.factor,
                "limiting": self.scaling.limiting, "ik_poses": int(len(self.ik.t)), "ik_unreachable": self.unreachable,
                "position_residual_max_m": float(self.ik.position_residual.max()),
                "angle_residual_max_rad": float(self.ik.angle_residual.max()), "notes": list(self.notes)}


def scene_task_frame(shelf_place: np.ndarray, table_place: np.ndarray) -> tuple[RigidTransform, np.ndarray]:
    """``X_world_task`` and the table place in the task frame (3,) for a scene's box places (world, m):
    the task frame's definition (:func:`~besdrake.tasks.pick_and_place.task_frame.task_frame`: origin on
    the shelf place, x horizontal towards the table place, z up)."""
    frame = task_frame(shelf_place, table_place)
    return RigidTransform(RotationMatrix(frame.rotation), frame.origin), frame.points(table_place)


def hand_to_tool(robot: Robot) -> RotationMatrix:
    """``R_hand_tool`` from the robot file's ``mapping.hand_to_tool_rpy`` (identity when absent)."""
    rpy = np.asarray(robot.mapping.get(HAND_TO_TOOL_KEY, [0.0, 0.0, 0.0]), dtype=float)
    if rpy.shape != (3,) or not np.isfinite(rpy).all():
        raise ValueError(f"{robot.path}: mapping.{HAND_TO_TOOL_KEY} must be [roll, pitch, yaw] in rad, got {rpy.tolist()}")
    return RotationMatrix(RollPitchYaw(rpy))


def gripper_widths(robot: Robot) -> tuple[float, float] | None:
    """(open, closed) distance between the pads (m) from the robot file; None without a gripper."""
    g = robot.end_effector.gripper
    return None if g is None else (2.0 * float(np.mean(g.open)), 2.0 * float(np.mean(g.closed)))


def gripper_command(skill: GraspSkill, robot: Robot, time_scale: float = 1.0,
                    close_duration: float = DEFAULT_CLOSE_DURATION) -> dict | None:
    """``{"t": [...], "width": [...]}`` for the skill's close and open times, scaled by ``time_scale``."""
    widths = gripper_widths(robot)
    if widths is None:
        return None
    w_open, w_closed = widths
    c = max(skill.close_time, 0.0)
    o = max(skill.open_time, c + close_duration)
    t = np.array([0.0, c, c + close_duration, o, o + close_duration]) * time_scale
    width = [w_open, w_open, w_closed, w_closed, w_open]
    keep = np.concatenate([[True], np.diff(t) > 1e-9])
    return {"t": t[keep].tolist(), "width": np.asarray(width)[keep].tolist()}


def tool_targets(skill: GraspSkill, X_base_task: RigidTransform, R_hand_tool: RotationMatrix,
                 dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The skill's rollout as tool poses in the base frame: times (n,), positions (n, 3), rotations (n, 3, 3)."""
    traj = skill.rollout(dt)
    R_bt = X_base_task.rotation().matrix()
    positions = traj.pose[:, :3] @ R_bt.T + X_base_task.translation()
    rotations = R_bt @ rotation_matrices(traj.pose[:, 3:]) @ R_hand_tool.matrix()
    return traj.t, positions, rotations


def start_from_home(skill: GraspSkill, model: KinematicModel, X_base_task: RigidTransform,
                     R_hand_tool: RotationMatrix) -> GraspSkill:
    """The skill with its approach starting at the tool pose of the robot's home position."""
    X_task_tool = X_base_task.inverse() @ model.tcp_pose(model.robot.home)
    hand = (X_task_tool.rotation() @ R_hand_tool.inverse()).ToQuaternion()
    skill.approach.position.start = X_task_tool.translation()
    skill.approach.orientation.start = np.array([hand.w(), hand.x(), hand.y(), hand.z()])
    return skill


def grasp_plan(
    skill_or_demo,
    robot: Robot | str,
    X_world_task: RigidTransform,
    X_world_base: RigidTransform | None = None,
    table_place: np.ndarray | None = None,
    grasp_offset: np.ndarray | None = None,
    start: str = "demonstration",
    ik_dt: float = 0.04,
    close_duration: float = DEFAULT_CLOSE_DURATION,
    safety: float = 0.9,
    ik_options: PoseIKOptions | None = None,
    model: KinematicModel | None = None,
) -> GraspPlan:
    """The plan of a grasp skill (or of a GraspDemonstration, imitated first) on ``robot`` (see the
    module docstring). ``table_place`` (3,) m in the task frame and ``grasp_offset`` (3,) m (tool minus
    box midpoint, task frame): see :meth:`GraspSkill.adapted`. ``start``: "demonstration" (the approach
    starts at the demonstrated pose) or "home" (at the tool pose of the robot's home position, where a
    simulation's arm stands: the plan then starts at the home joint positions). ``model``: the robot's :func:`welded_plant` (built when not given)."""
    robot = load_robot(robot)
    model = model or welded_plant(robot)
    skill = skill_or_demo if isinstance(skill_or_demo, GraspSkill) else GraspSkill.from_demonstration(
        skill_or_demo, close_duration=close_duration)
    X_base_task = (X_world_base or RigidTransform()).inverse() @ X_world_task
    R_ht = hand_to_tool(robot)
    skill = skill.adapted(table_place, grasp_offset)
    if start == "home":
        skill = start_from_home(skill, model, X_base_task, R_ht)
    elif start != "demonstration":
        raise ValueError(f"start must be 'demonstration' or 'home', got {start!r}")
    t, positions, rotations = tool_targets(skill, X_base_task, R_ht, ik_dt)
    seed = np.asarray(robot.mapping.get("ik_seed", robot.home), dtype=float) if start == "demonstration" else robot.home
    if start == "home":  # the plan must start where the arm stands: the home branch, no backward pass
        ik_options = dataclasses.replace(ik_options or PoseIKOptions(), n_branches=1, backward_pass=False)
    ik = pose_ik_trajectory(model, t, positions, rotations, seed, options=ik_options)
    scaling = temporal_scaling(t, ik.q, robot.limits, safety=safety, min_duration=0.0)
    notes = []
    if ik.reachable.sum() < len(t):
        notes.append(f"{int((~ik.reachable).sum())} of {len(t)} tool poses unreachable "
                     f"(largest miss {ik.position_residual.max() * 1000:.0f} mm, {np.degrees(ik.angle_residual.max()):.0f} deg)")
    meta = {"source": "grasp_imitation", "demonstration": skill.source, "ik_unreachable": int((~ik.reachable).sum())}
    plan, scaling = _scaled_plan(t, ik.q, robot, scaling, safety, meta)
    command = gripper_command(skill, robot, scaling.factor, close_duration)
    if command is None:
        notes.append(f"robot {robot.name!r} has no gripper: the plan carries no gripper command")
    else:
        plan.meta["gripper"] = command
    quats = np.array([_quaternion(R) for R in rotations])
    return GraspPlan(plan, skill, ik, scaling, positions, quats, X_base_task, notes)


def with_lead_in(plan: MotionPlan, q_from: np.ndarray, robot: Robot, safety: float = 0.9) -> MotionPlan:
    """``plan`` preceded by a rest-to-rest quintic joint move from ``q_from`` (e.g. where the arm stands) to
    its start, as short as ``safety`` x the velocity and acceleration limits allow (a quintic's peaks:
    1.875 d / T and 5.774 d / T**2 for a step d); the gripper command's times are shifted with the arm's."""
    d = np.abs(plan.q[0] - np.asarray(q_from, dtype=float))
    T = max(float(np.max(1.875 * d / (safety * robot.velocity_limits))),
            float(np.sqrt(np.max(5.774 * d / (safety * robot.acceleration_limits)))), 0.1)
    s = np.linspace(0.0, 1.0, max(3, int(np.ceil(T / 0.02)) + 1))
    blend = 10 * s**3 - 15 * s**4 + 6 * s**5
    q_in = q_from + blend[:, None] * (plan.q[0] - q_from)
    qd_in = ((30 * s**2 - 60 * s**3 + 30 * s**4) / T)[:, None] * (plan.q[0] - q_from)
    meta = dict(plan.meta, lead_in_s=T)
    if "gripper" in meta:
        meta["gripper"] = {"t": [0.0] + [t + T for t in meta["gripper"]["t"]],
                           "width": [meta["gripper"]["width"][0]] + list(meta["gripper"]["width"])}
    qd = plan.knot_velocities()
    return MotionPlan(t=np.concatenate([s * T, plan.t[1:] + T]), q=np.vstack([q_in, plan.q[1:]]),
                      qd=np.vstack([qd_in, qd[1:]]), meta=meta, joint_names=plan.joint_names).validate()


def _scaled_plan(t: np.ndarray, q: np.ndarray, robot: Robot, scaling: TemporalScaling, safety: float,
                 meta: dict) -> tuple[MotionPlan, TemporalScaling]:
    """The plan through ``q`` at times stretched by the scaling's factor, stretched further when its
    interpolating spline (what the robot is commanded) peaks above ``safety`` x the limits between the
    samples the factor was computed from (a uniform stretch by ``k`` divides velocities by ``k`` and
    accelerations by ``k**2``, so one correction is exact)."""
    k = scaling.factor
    plan = _interpolated_plan((t - t[0]) * k, q, robot, meta)
    v, a = plan.peak_limit_ratios(robot.limits)
    extra = max(1.0, float(v.max()) / safety, float(np.sqrt(a.max() / safety)))
    if extra > 1.0:
        scaling.factor, scaling.duration = k * extra, scaling.duration * extra
        scaling.limiting += " (between samples)"
        plan = _interpolated_plan(plan.t * extra, q, robot, meta)
    plan.meta["time_scale"] = scaling.factor
    return plan, scaling


def _interpolated_plan(t: np.ndarray, q: np.ndarray, robot: Robot, meta: dict) -> MotionPlan:
    """A plan through ``q``: the smooth not-a-knot spline (no ``qd``), or, where that overshoots a
    position limit between two samples, shape-preserving PCHIP knot velocities (no joint then leaves
    the range of its two samples, so IK solutions within the limits give a plan within them)."""
    from scipy.interpolate import PchipInterpolator

    plan = MotionPlan(t=t, q=q, meta=meta, joint_names=robot.joint_names).validate()
    if np.any(plan.check_limits(robot.limits).position > 0):
        plan.qd = PchipInterpolator(t, q, axis=0).derivative()(t)
    return plan


def _quaternion(R: np.ndarray) -> np.ndarray:
    q = RotationMatrix(R).ToQuaternion()
    return np.array([q.w(), q.x(), q.y(), q.z()])
