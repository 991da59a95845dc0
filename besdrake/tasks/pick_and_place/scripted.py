"""A scripted pick-and-place plan from inverse kinematics: the reference that shows the simulation can succeed.

Tool poses (the robot's tool frame: +z the approach axis, +y the fingers' closing line) are placed relative to the
box on the shelf and the target place on the table: approach the box horizontally from the robot's side, close,
lift, pull back out of the shelf, carry it (through a point above and between shelf and table) over the table, lower it onto the place, open, pull back. Each pose is
solved by Drake's ``InverseKinematics`` within the joint limits less 0.05 rad, the grasp from the robot file's
``mapping.ik_seed``, the others from a neighbouring pose (:data:`SOLVE_ORDER`), turned about the base's vertical
first joint by the change of approach direction (so the arm keeps its posture from the shelf to the table), and the plan
moves between them in joint space, at rest at each pose (cubic Hermite with zero end velocities).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from besdrake.plan import MotionPlan
from besdrake.robot import Robot
from besdrake.tasks.pick_and_place.gripper import GripperCommand, open_width


class IKError(RuntimeError):
    """Inverse kinematics found no joint configuration for a tool pose."""


@dataclass(frozen=True)
class ScriptTiming:
    """Shortest durations (s) of the plan's segments; a segment is stretched where the robot's velocity or
    acceleration limits need it (:func:`segment_time`)."""

    to_pregrasp: float = 1.0
    approach: float = 0.6
    close: float = 0.4
    lift: float = 0.4
    pull_out: float = 0.5
    transport: float = 1.8
    lower: float = 0.5
    open: float = 0.3
    retreat: float = 0.5


def _tool_rotation(approach: np.ndarray):
    """Tool orientation with +z along the horizontal ``approach`` and +y horizontal (fingers close sideways)."""
    from pydrake.math import RotationMatrix

    z = np.array([approach[0], approach[1], 0.0]) / np.linalg.norm(approach[:2])
    y = np.cross([0.0, 0.0, 1.0], z)
    return RotationMatrix(np.column_stack([np.cross(y, z), y, z]))


class ToolIK:
    """Inverse kinematics of a robot's tool frame, its base welded at ``X_WB``; gripper joints held at ``grip``."""

    def __init__(self, robot: Robot, X_WB) -> None:
        from pydrake.multibody.plant import MultibodyPlant

        self.robot = robot
        self.plant = MultibodyPlant(0.0)
        instance = robot.add_model(self.plant)
        self.plant.WeldFrames(self.plant.world_frame(), self.plant.GetFrameByName(robot.base_link, instance), X_WB)
        self.plant.Finalize()
        self.tool = self.plant.GetFrameByName(robot.tool_frame, instance)
        self.arm = np.array([self.plant.GetJointByName(j, instance).position_start() for j in robot.joint_names])
        self.context = self.plant.CreateDefaultContext()

    def solve(self, p_W: np.ndarray, R_W, q_seed: np.ndarray, pos_tol: float = 1e-3, rot_tol: float = 0.01,
              margin: float = 0.05) -> np.ndarray:
        """Arm joints (rad) that put the tool at ``p_W`` with orientation ``R_W``, within the joint limits less
        ``margin`` (rad), near ``q_seed``: solved from the seed; if that fails, from other starts
        (:meth:`_starts`), keeping the solution closest to the seed."""
        from pydrake.math import RotationMatrix
        from pydrake.multibody.inverse_kinematics import InverseKinematics
        from pydrake.solvers import Solve

        ik = InverseKinematics(self.plant, with_joint_limits=True)
        q = ik.q()
        ik.AddPositionConstraint(self.tool, np.zeros(3), self.plant.world_frame(), p_W - pos_tol, p_W + pos_tol)
        ik.AddOrientationConstraint(self.tool, RotationMatrix(), self.plant.world_frame(), R_W, rot_tol)
        prog = ik.get_mutable_prog()
        lim = self.robot.position_limits
        prog.AddBoundingBoxConstraint(lim[:, 0] + margin, lim[:, 1] - margin, q[self.arm])
        full_seed = self.plant.GetPositions(self.context)
        for i in np.setdiff1d(np.arange(len(full_seed)), self.arm):
            prog.AddBoundingBoxConstraint(full_seed[i], full_seed[i], q[i])
        prog.AddQuadraticErrorCost(np.eye(len(self.arm)), q_seed, q[self.arm])
        found = []
        for k, start in enumerate(self._starts(q_seed)):
            full_seed[self.arm] = start
            result = Solve(prog, full_seed)
            if result.is_success():
                found.append(result.GetSolution(q)[self.arm])
                if k == 0:
                    break
        if not found:
            raise IKError(f"no IK solution for the tool at {np.round(p_W, 3).tolist()} ({result.get_solver_id().name()})")
        return min(found, key=lambda x: float(np.linalg.norm(x - q_seed)))

    def _starts(self, q_seed: np.ndarray, n_random: int = 12):
        """Initial guesses: the seed, the robot file's ``mapping.ik_seed``, then random poses within the limits
        (a fixed random stream: the same plan every time)."""
        yield q_seed
        if "ik_seed" in self.robot.mapping:
            yield np.asarray(self.robot.mapping["ik_seed"], dtype=float)
        lim = self.robot.position_limits
        rng = np.random.default_rng(0)
        for _ in range(n_random):
            yield rng.uniform(lim[:, 0], lim[:, 1])


#: Height of the grasp on the box, as a fraction of the box's height from its bottom. High on the box, so that the
#: wrist clears the boards with a horizontal gripper: a Panda's hand reaches 5 cm below the fingertips' axis (it
#: touched the shelf board at 0.5) and its link 7 7 cm below, 6-20 cm behind the fingertips (it touched the table top
#: when putting the box down at 0.7); the box hangs below the grip.
GRASP_HEIGHT = 0.85


def waypoints(box_start: np.ndarray, box_height: float, place: np.ndarray, base: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Named tool poses {name: (position m, horizontal approach direction)} of the scripted pick and place."""
    up = np.array([0.0, 0.0, 1.0])
    grasp = box_start + GRASP_HEIGHT * box_height * up
    put = place + (GRASP_HEIGHT * box_height + 0.003) * up
    a = np.r_[(box_start - base)[:2], 0.0]
    a /= np.linalg.norm(a)
    b = np.r_[(place - base)[:2], 0.0]
    b /= np.linalg.norm(b)
    mid = (a + b) / np.linalg.norm(a + b)
    radius = 0.5 * (np.linalg.norm((grasp - base)[:2]) + np.linalg.norm((put - base)[:2])) - 0.1
    via = np.r_[base[:2] + radius * mid[:2], max(grasp[2], put[2]) + 0.1]
    return {
        "pregrasp": (grasp - 0.12 * a, a),
        "grasp": (grasp, a),
        "lift": (grasp + 0.06 * up, a),
        "pull_out": (grasp + 0.06 * up - 0.15 * a, a),
        "via": (via, mid),
        "preplace": (put + 0.06 * up, b),
        "place": (put, b),
        "retreat": (put - 0.12 * b, b),
    }


#: Order in which the poses are solved and the pose each one starts from (None: the robot file's ik_seed): the
#: grasp first, its neighbours from it; the place from the grasp (turned about the base), its neighbours from it.
SOLVE_ORDER = (("grasp", None), ("pregrasp", "grasp"), ("lift", "grasp"), ("pull_out", "lift"), ("place", "grasp"),
               ("preplace", "place"), ("retreat", "place"), ("via", "pull_out"))


def _yaw(a: np.ndarray) -> float:
    return float(np.arctan2(a[1], a[0]))


def solve_waypoints(robot: Robot, ik: "ToolIK", poses: dict) -> dict[str, np.ndarray]:
    """Joint configurations of the named tool poses (see :data:`SOLVE_ORDER`). A seed taken from another pose is
    turned about the base's vertical first joint by the change of approach direction, so the arm keeps its posture
    from the shelf to the table."""
    seed0 = np.asarray(robot.mapping.get("ik_seed", robot.home), dtype=float)
    out: dict[str, np.ndarray] = {}
    for name, source in SOLVE_ORDER:
        p, a = poses[name]
        seed = seed0.copy() if source is None else out[source].copy()
        if source is not None:
            seed[0] += _yaw(a) - _yaw(poses[source][1])
        out[name] = ik.solve(p, _tool_rotation(a), robot.limits.clip(seed, margin=0.05))
    return out


def segment_time(robot: Robot, dq: np.ndarray, margin: float = 1.1) -> float:
    """Shortest duration (s) of a rest-to-rest cubic over ``dq`` (rad) within the robot's velocity and acceleration
    limits (peak velocity 1.5 |dq| / T, peak acceleration 6 |dq| / T^2), times ``margin``."""
    dq = np.abs(dq)
    return margin * float(max(np.max(1.5 * dq / robot.velocity_limits), np.max(np.sqrt(6 * dq / robot.acceleration_limits))))


def scripted_plan(robot: Robot, X_WB, box_start: np.ndarray, box_height: float, place: np.ndarray,
                  timing: ScriptTiming | None = None, q_start: np.ndarray | None = None) -> MotionPlan:
    """The scripted pick-and-place plan from ``q_start`` (default: the robot's home pose); the gripper command is
    in ``meta["gripper"]`` (open, closed from the grasp until the place, open again)."""
    timing = timing or ScriptTiming()
    ik = ToolIK(robot, X_WB)
    poses = solve_waypoints(robot, ik, waypoints(np.asarray(box_start), box_height, np.asarray(place), X_WB.translation()))
    t = timing
    seq = [(0.0, q_start if q_start is not None else robot.home), (t.to_pregrasp, poses["pregrasp"]),
           (t.approach, poses["grasp"]), (t.close, poses["grasp"]), (t.lift, poses["lift"]),
           (t.pull_out, poses["pull_out"]), (t.transport / 2, poses["via"]), (t.transport / 2, poses["preplace"]), (t.lower, poses["place"]),
           (t.open, poses["place"]), (t.retreat, poses["retreat"])]
    qs = np.array([np.asarray(qq, dtype=float) for _, qq in seq])
    durations = [0.0] + [max(d, segment_time(robot, qs[i + 1] - qs[i])) for i, (d, _) in enumerate(seq[1:])]
    times = np.cumsum(durations)
    w_open = open_width(robot)
    t_close, t_open = times[2], times[8]
    grip = GripperCommand(np.array([0.0, t_close, t_close + 0.3, t_open, t_open + 0.25]),
                          np.array([w_open, w_open, 0.0, 0.0, w_open]))
    return MotionPlan(t=times, q=qs, qd=np.zeros_like(qs), meta={"gripper": grip.to_meta(), "script": "pick_and_place"},
                      joint_names=robot.joint_names)


def scripted_plan_for(rollout, timing: ScriptTiming | None = None) -> MotionPlan:
    """:func:`scripted_plan` for a :class:`~besdrake.tasks.pick_and_place.rollout.PickPlaceRollout`'s scene and robot."""
    from besdrake.sim.diagram import base_transform

    h = rollout.h
    return scripted_plan(rollout.robot, base_transform(rollout.scenario), rollout.box_start, 2 * h.box_half_size[2],
                         rollout.place_target, timing)
