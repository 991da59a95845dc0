"""Grasp skills to motion plans in a pick-and-place scene: the step every rollout of a policy search repeats.

:class:`SkillPlanner` holds what does not change between candidates (the robot's welded plant, the task frame in the
robot's base frame, the scene's box places and size) and turns a :class:`~besdrake.tasks.pick_and_place.imitation.GraspSkill`
into a :class:`~besdrake.plan.MotionPlan` in four steps:

1. :meth:`SkillPlanner.adapt`: the skill's goals are set to the scene (the approach ends with the tool at the box's
   middle on the shelf, the transport with the box's middle over the table place, plus the demonstrated release
   offset) and its approach starts at the tool pose of the robot's home position (where the arm stands): the
   demonstrated reach from the person's resting hand is cropped and the rest warped onto that start
   (:meth:`~besdrake.tasks.pick_and_place.imitation.GraspSkill.reaching_from`);
2. the skill's rollout, as tool poses in the base frame (``mapping.hand_to_tool_rpy`` of the robot file);
3. resolved-rate path IK from the home position (:class:`~besdrake.embodiment.path_ik.PathIK`: continuous joints,
   the tool lagging where a pose is out of reach);
4. time-optimal retiming under ``safety`` x the velocity and acceleration limits
   (:func:`~besdrake.embodiment.scaling.toppra_retime`; where Toppra fails at a sharp bend of the spline through
   every IK sample, on every 2nd, then 3rd sample (a smoother spline); where all fail, a per-interval stretch:
   :func:`~besdrake.embodiment.scaling.local_retime`), a last uniform
   stretch if the plan's spline peaks above the limits between samples, and the gripper command's close and open
   times carried through the same time map.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RotationMatrix

from besdrake.embodiment.kinematics import KinematicModel, welded_plant
from besdrake.embodiment.path_ik import PathIK, PathIKOptions
from besdrake.embodiment.pose_ik import PoseIKTrajectory
from besdrake.embodiment.scaling import local_retime, toppra_retime
from besdrake.plan import MotionPlan
from besdrake.robot import Robot
from besdrake.tasks.pick_and_place.grasp_plan import (gripper_command, hand_to_tool, scene_task_frame,
                                                      start_from_home, tool_targets)
from besdrake.tasks.pick_and_place.imitation import GraspSkill

#: Fraction of the velocity and acceleration limits a plan may use.
DEFAULT_SAFETY = 0.85


@dataclass
class SkillPlan:
    """A skill's plan and how well the arm follows the skill's tool path (residuals in m and rad)."""

    plan: MotionPlan
    skill: GraspSkill
    ik: PoseIKTrajectory
    retiming: str  # "toppra", "toppra/2".. (Toppra on every 2nd.. IK sample) or "local"
    notes: list[str] = field(default_factory=list)

    def summary(self) -> dict:
        """JSON-ready figures (SI units)."""
        return {"duration_s": self.plan.duration, "retiming": self.retiming,
                "position_lag_max_m": float(self.ik.position_residual.max()),
                "angle_lag_max_rad": float(self.ik.angle_residual.max()),
                "poses_off_path": int((~self.ik.reachable).sum()), "poses": int(len(self.ik.t)),
                "notes": list(self.notes)}


class SkillPlanner:
    """Plans grasp skills for ``robot`` in a scene with the box's bottom centre at ``box_start`` on the shelf and
    its target place ``place_target`` on the table (world, m), the robot's base at ``X_world_base``."""

    def __init__(self, robot: Robot, X_world_base, box_start: np.ndarray, place_target: np.ndarray,
                 box_height: float, safety: float = DEFAULT_SAFETY, ik_dt: float = 0.02,
                 ik_options: PathIKOptions | None = None, model: KinematicModel | None = None,
                 box_rotation: RotationMatrix | None = None) -> None:
        self.robot, self.safety, self.ik_dt = robot, float(safety), float(ik_dt)
        self.model = model or welded_plant(robot)
        self.path_ik = PathIK(self.model, ik_options)
        X_world_task, self.table_place = scene_task_frame(np.asarray(box_start, float), np.asarray(place_target, float))
        self.X_base_task = X_world_base.inverse() @ X_world_task
        R_task_box = X_world_task.rotation().inverse() @ (box_rotation or RotationMatrix())
        self.box_face_normals = R_task_box.matrix()[:, :2].T  # the box's side faces' normals (x, y) in the task frame
        self.default_R_hand_tool = hand_to_tool(robot)
        self.grasp_offset = np.array([0.0, 0.0, 0.5 * float(box_height)])

    @classmethod
    def for_rollout(cls, rollout, box_offset=None, **kwargs) -> "SkillPlanner":
        """The planner of a :class:`~besdrake.tasks.pick_and_place.rollout.PickPlaceRollout`'s scene; ``box_offset``
        (dx, dy m in the world, as the rollout's): the box stands that far from the scene's place on the shelf."""
        from besdrake.sim.diagram import base_transform

        box_start = np.asarray(rollout.box_start, dtype=float).copy()
        if box_offset is not None:
            box_start[:2] += np.asarray(box_offset, dtype=float)[:2]
        return cls(rollout.robot, base_transform(rollout.scenario), box_start, rollout.place_target,
                   2.0 * float(rollout.h.box_half_size[2]), box_rotation=rollout.h.box_start.rotation(), **kwargs)

    def adapt(self, skill: GraspSkill) -> GraspSkill:
        """``skill`` with the scene's goals and its approach starting at the home tool pose (step 1)."""
        turned = self._nearer_closing_sign(self._across_faces(skill.copy()))
        return self._from_home(turned.adapted(self.table_place + self.grasp_offset, self.grasp_offset))

    def carry_over(self, skill: GraspSkill) -> GraspSkill:
        """A skill adapted (and perhaps refined) in a scene with the box elsewhere on the shelf, moved into this one:
        its goals keep their offsets from the box places (the task frame moves with the box), its approach starts
        again from the home tool pose."""
        table = self.table_place + self.grasp_offset
        new = skill.copy()
        new.transport.position.goal = table + (skill.transport.position.goal - skill.table_place)
        new.table_place = table
        return self._from_home(new)

    def _from_home(self, skill: GraspSkill) -> GraspSkill:
        """``skill`` with its approach reaching from the home tool pose (cropped and warped onto it) and starting there
        in the home orientation."""
        home = (self.X_base_task.inverse() @ self.model.tcp_pose(self.robot.home)).translation()
        skill = skill.reaching_from(home)
        return start_from_home(skill, self.model, self.X_base_task, self.hand_to_tool(skill))

    def _across_faces(self, skill: GraspSkill) -> GraspSkill:
        """The demonstrated closing line turned onto the nearest normal of the box's side faces: a hand closes on a box
        at a slant and still holds it, a parallel gripper's pads must lie flat on two opposite faces (and a narrow
        gripper opens only as wide as the box, not as its diagonal)."""
        closing = skill.closing_axis_hand
        if not np.isfinite(closing).all():
            return skill
        R_task_hand = RotationMatrix(Quaternion(_unit(skill.approach.orientation.goal))).matrix()
        c = R_task_hand @ closing
        n = self.box_face_normals[int(np.argmax(np.abs(self.box_face_normals @ c)))]
        skill.closing_axis_hand = R_task_hand.T @ (n * np.sign(n @ c))
        return skill

    def _nearer_closing_sign(self, skill: GraspSkill) -> GraspSkill:
        """A parallel gripper grips alike turned half a turn about its approach axis: of the two, the skill keeps
        the closing line (its sign) whose grasp orientation is nearer the tool's at home, so that the arm turns
        the tool less on its way to the box (robot file ``mapping.tool_closing_symmetric``, default true)."""
        if not self.robot.mapping.get("tool_closing_symmetric", True) or not np.isfinite(skill.closing_axis_hand).all():
            return skill
        R_home = self.model.tcp_pose(self.robot.home).rotation()
        R_hand = self.X_base_task.rotation() @ RotationMatrix(Quaternion(_unit(skill.approach.orientation.goal)))

        def turn(closing: np.ndarray) -> float:
            flipped = dataclasses.replace(skill, closing_axis_hand=closing)
            return abs(R_home.InvertAndCompose(R_hand @ self.hand_to_tool(flipped)).ToAngleAxis().angle())

        if turn(-skill.closing_axis_hand) < turn(skill.closing_axis_hand):
            skill.closing_axis_hand = -skill.closing_axis_hand
        return skill

    def hand_to_tool(self, skill: GraspSkill) -> RotationMatrix:
        """``R_hand_tool`` from the demonstrated grasp: the tool's closing axis (robot file
        ``mapping.tool_closing_axis``, default +y) along the skill's thumb-to-fingers line and its approach axis
        (``mapping.tool_axis``, default +z) towards the grasp point, both in the hand plate frame; the robot file's
        ``mapping.hand_to_tool_rpy`` when the demonstration measured no closing line."""
        closing = np.asarray(skill.closing_axis_hand, dtype=float)
        if not np.isfinite(closing).all():
            return self.default_R_hand_tool
        tool_closing = np.asarray(self.robot.mapping.get("tool_closing_axis", [0.0, 1.0, 0.0]), dtype=float)
        return RotationMatrix(_align(self.model.tool_axis, tool_closing, skill.grasp_offset_hand, closing))

    def plan(self, skill: GraspSkill) -> SkillPlan:
        """The plan of an adapted skill (steps 2-4); the arm starts at the robot's home position."""
        robot = self.robot
        t, positions, rotations = tool_targets(skill, self.X_base_task, self.hand_to_tool(skill), self.ik_dt)
        ik = self.path_ik.follow(t, positions, rotations, robot.home)
        retimed, retiming = self._toppra(t, ik.q)
        if retimed is None:
            t_new, t_path = local_retime(t, ik.q, robot.limits, safety=self.safety)
            retimed, retiming = (t_new, ik.q, t_path), "local"
        t_plan, q_plan, t_path = retimed
        plan = MotionPlan(t=t_plan, q=q_plan, joint_names=robot.joint_names,
                          meta={"source": "grasp_skill", "demonstration": skill.source}).validate()
        stretch = self._stretch(plan)
        if stretch > 1.0:
            plan = MotionPlan(t=plan.t * stretch, q=plan.q, joint_names=robot.joint_names, meta=plan.meta).validate()
            t_plan = plan.t
        command = gripper_command(skill, robot)
        if command is not None:
            command["t"] = [self._plan_time(x, t_path, t_plan) for x in command["t"]]
            plan.meta["gripper"] = command
        notes = [] if ik.reachable.all() else [
            f"{int((~ik.reachable).sum())} of {len(t)} tool poses off the path (largest lag "
            f"{ik.position_residual.max() * 1000:.0f} mm, {np.degrees(ik.angle_residual.max()):.0f} deg)"]
        return SkillPlan(plan, skill, ik, retiming, notes)

    def _toppra(self, t: np.ndarray, q: np.ndarray, strides=(1, 2, 3)):
        """Toppra on the IK path, on every ``stride``-th sample (and the last) until it succeeds: ``(result, label)``,
        ``(None, "")`` when it fails on all."""
        for stride in strides:
            idx = np.unique(np.r_[np.arange(0, len(t), stride), len(t) - 1])
            retimed = toppra_retime(t[idx], q[idx], self.robot.limits, self.model, safety=self.safety,
                                    max_duration=self.robot.safety.max_plan_duration)
            if retimed is not None:
                return retimed, "toppra" if stride == 1 else f"toppra/{stride}"
        return None, ""

    def _stretch(self, plan: MotionPlan) -> float:
        """Uniform stretch that brings the plan's spline within ``safety`` x the limits between samples."""
        v, a = plan.peak_limit_ratios(self.robot.limits)
        return max(1.0, float(v.max()) / self.safety, float(np.sqrt(a.max() / self.safety)))

    @staticmethod
    def _plan_time(t_skill: float, t_path: np.ndarray, t_plan: np.ndarray) -> float:
        """Plan time of skill time ``t_skill`` (after the path's end: as much later as in the skill)."""
        if t_skill <= t_path[-1]:
            return float(np.interp(t_skill, t_path, t_plan))
        return float(t_plan[-1] + t_skill - t_path[-1])


def _unit(q: np.ndarray) -> np.ndarray:
    return np.asarray(q, dtype=float) / np.linalg.norm(q)


def _frame(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Orthonormal columns (a, b', a x b') with b' the part of b orthogonal to a."""
    a = a / np.linalg.norm(a)
    b = b - a * (a @ b)
    b = b / np.linalg.norm(b)
    return np.column_stack([a, b, np.cross(a, b)])


def _align(tool_a: np.ndarray, tool_b: np.ndarray, hand_a: np.ndarray, hand_b: np.ndarray) -> np.ndarray:
    """The rotation (tool in hand) taking tool axis ``tool_a`` to ``hand_a`` and ``tool_b`` as near ``hand_b`` as
    an orthogonal frame allows (``hand_b`` is kept exactly, ``hand_a`` made orthogonal to it)."""
    return _frame(hand_b, hand_a) @ _frame(tool_b, tool_a).T
