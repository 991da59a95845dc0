"""Synchronization frame: where to put the demonstration relative to the robot's base.

Paper section 2.3.2: the frame in which the demonstration is replayed is free; choose it so that
every demonstrated hand pose has an inverse-kinematics solution and the joint trajectory is
smooth (small velocity, acceleration and jerk, no jumps).

We solve this as **one** nonlinear program (SNOPT through Drake's MathematicalProgram) on the
:func:`~besdrake.embodiment.kinematics.mounted_plant`, whose six mount coordinates are the
pose of the robot's base in the demonstrator's back frame. Decision variables: the mount ``m`` (6)
and one joint configuration ``q_i`` (n joints) per sampled pose. Costs:

* pose: Drake ``PositionCost`` (tool origin to hand centre, weight ``position_weight`` per m^2)
  and ``AngleBetweenVectorsCost`` (the robot file's tool axis to the palm normal, weight ``angle_weight`` on
  ``1 - cos``), both evaluated on ``[m, q_i]``;
* smoothness: squared first, second and third finite differences of every joint (rad), a convex
  quadratic in ``Q``;
* holding (``hold_cone_deg``, off by default here, set by the embodiment mapping): the tool
  axis within a cone around the base's vertical at every sampled pose (Drake
  ``AngleBetweenVectorsConstraint``), a task constraint the demonstration does not carry: a human
  palm faces forward while it holds an object, an open tool turned that way drops it;
* bounds: joint limits shrunk by a margin; the mount within a box around the nominal placement
  (the base's z up, its x towards the demonstrator's front, so the demonstrated movement points to
  the targets in front of the robot).

Pose terms are costs, not constraints, so an unreachable demonstration still gives the best frame
and the residuals say which poses miss by how much. A few starting guesses are tried (the program
is non-convex) and the lowest cost wins.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from pydrake.solvers import MathematicalProgram, SnoptSolver, SolverOptions
from pydrake.multibody.inverse_kinematics import (
    AngleBetweenVectorsConstraint,
    AngleBetweenVectorsCost,
    PositionConstraint,
    PositionCost,
)

from besdrake.embodiment.kinematics import KinematicModel, mount_to_transform
from besdrake.embodiment.record_mapping import HandTrajectory


@dataclass
class SyncFrameOptions:
    """Weights and bounds of the synchronization-frame program."""

    n_poses: int = 20
    position_weight: float = 1.0e4  # per m^2
    angle_weight: float = 10.0  # on (1 - cos angle)
    velocity_weight: float = 1.0
    acceleration_weight: float = 1.0
    jerk_weight: float = 1.0
    joint_margin: float = 0.1  # rad kept from every position limit
    mount_lower: tuple[float, ...] = (-1.5, -1.5, -1.5, -0.6, -0.35, -0.35)
    mount_upper: tuple[float, ...] = (1.5, 1.5, 1.5, 0.6, 0.35, 0.35)
    position_tolerance: float = 0.0005  # m, half-width of the position box when reachable
    major_iterations: int = 400
    hold_cone_deg: float | None = None  # tool axis within this angle of the base's vertical at every pose (None: free)


@dataclass
class SyncFrameResult:
    """The synchronization frame and the joint configurations at the sampled poses."""

    mount: np.ndarray  # (6,) x, y, z, yaw, pitch, roll of the robot's base in the back frame
    q: np.ndarray  # (n, joints) joint positions at the sampled poses
    t: np.ndarray  # (n,) times of the sampled poses
    position_residual: np.ndarray  # (n,) m
    angle_residual: np.ndarray  # (n,) rad
    cost: float
    solve_time_s: float
    n_starts: int
    info: dict = field(default_factory=dict)

    @property
    def base_in_back(self) -> np.ndarray:
        """4x4 pose of the robot's base in the demonstrator's back frame."""
        return mount_to_transform(self.mount).GetAsMatrix4()

    @property
    def back_in_base(self) -> np.ndarray:
        """4x4 pose of the demonstrator's back frame in the robot's base frame: the synchronization frame."""
        return mount_to_transform(self.mount).inverse().GetAsMatrix4()


def _difference_hessian(n: int, opts: SyncFrameOptions) -> np.ndarray:
    h = np.zeros((n, n))
    for order, w in ((1, opts.velocity_weight), (2, opts.acceleration_weight), (3, opts.jerk_weight)):
        if w > 0 and n > order:
            d = np.diff(np.eye(n), order, axis=0)
            h += w * d.T @ d
    return h


def _initial_guesses(hand: HandTrajectory, q_up: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Mount and joint guesses: the base about 0.6-0.9 m below the hand path's centre, the arm at ``q_up``."""
    centre = hand.position.mean(axis=0)
    guesses = []
    for dx, dz in ((-0.3, -0.7), (0.0, -0.9), (-0.5, -0.5)):
        mount = np.array([centre[0] + dx, centre[1], centre[2] + dz, 0.0, 0.0, 0.0])
        guesses.append((mount, q_up))
    return guesses


def solve_sync_frame(
    hand: HandTrajectory,
    options: SyncFrameOptions | None = None,
    model: KinematicModel | None = None,
    hard: bool = True,
) -> SyncFrameResult:
    """Optimise the synchronization frame for one demonstrated segment (see module docstring) on ``model``,
    a :func:`~besdrake.embodiment.kinematics.mounted_plant` of the robot."""
    if model is None or model.n_mount != 6:
        raise ValueError("solve_sync_frame needs model=mounted_plant(robot)")
    opts = options or SyncFrameOptions()
    poses = hand.resample(opts.n_poses) if len(hand.t) != opts.n_poses else hand
    prog, m, Q, _contexts = _sync_program(model, poses, opts, hard)  # the contexts live as long as the program
    t0 = time.perf_counter()
    guesses = _initial_guesses(poses, model.ik_seed)
    best = _best_solution(prog, m, Q, guesses, opts, len(poses.t))
    elapsed = time.perf_counter() - t0
    if best is None:
        raise RuntimeError("the synchronization-frame program failed from every starting guess")
    cost, mount, q, info = best
    pos_res, ang_res = pose_residuals(model, mount, q, poses)
    return SyncFrameResult(
        mount=mount,
        q=q,
        t=poses.t,
        position_residual=pos_res,
        angle_residual=ang_res,
        cost=float(cost),
        solve_time_s=elapsed,
        n_starts=len(guesses),
        info={"snopt_info": int(info)},
    )


def _sync_program(model: KinematicModel, poses: HandTrajectory, opts: SyncFrameOptions, hard: bool):
    """The program over the mount (6) and the joints at every pose (n, joints): tool on the hand's positions (hard
    constraints or costs), tool axis along the palm axis, within a cone of the base's vertical if asked, joints within
    their limits less a margin, smooth joint paths, the mount within its bounds: ``(prog, m, Q, contexts)``."""
    plant, robot, tool_axis, tcp = model.plant, model.robot, model.tool_axis, model.tcp
    n = len(poses.t)
    base = plant.GetFrameByName(robot.base_link)
    prog = MathematicalProgram()
    m = prog.NewContinuousVariables(6, "mount")
    Q = prog.NewContinuousVariables(n, robot.n_joints, "q")
    contexts = [plant.CreateDefaultContext() for _ in range(n)]
    for i in range(n):
        xi = np.concatenate([m, Q[i]])
        if hard:
            tol = opts.position_tolerance
            prog.AddConstraint(
                PositionConstraint(plant, plant.world_frame(), poses.position[i] - tol, poses.position[i] + tol, tcp, np.zeros(3), contexts[i]),
                xi,
            )
        else:
            prog.AddCost(
                PositionCost(plant, plant.world_frame(), poses.position[i], tcp, np.zeros(3), opts.position_weight * np.eye(3), contexts[i]),
                xi,
            )
        if opts.angle_weight > 0:
            prog.AddCost(
                AngleBetweenVectorsCost(plant, plant.world_frame(), poses.palm_axis[i], tcp, tool_axis, opts.angle_weight, contexts[i]),
                xi,
            )
        if opts.hold_cone_deg is not None:
            prog.AddConstraint(
                AngleBetweenVectorsConstraint(
                    plant, base, np.array([0.0, 0.0, 1.0]), tcp, tool_axis, 0.0, np.radians(opts.hold_cone_deg), contexts[i]
                ),
                xi,
            )
        prog.AddBoundingBoxConstraint(robot.position_limits[:, 0] + opts.joint_margin, robot.position_limits[:, 1] - opts.joint_margin, Q[i])
    hess = _difference_hessian(n, opts)
    for j in range(robot.n_joints):
        prog.AddQuadraticCost(2.0 * hess, np.zeros(n), Q[:, j], is_convex=True)
    prog.AddBoundingBoxConstraint(np.array(opts.mount_lower), np.array(opts.mount_upper), m)
    return prog, m, Q, contexts


def _best_solution(prog, m, Q, guesses, opts: SyncFrameOptions, n: int):
    """SNOPT from every guess: ``(cost, mount, q, info)`` of the lowest finite cost, or None."""
    solver = SnoptSolver()
    if not solver.available():  # pragma: no cover - SNOPT ships with the drake wheel
        raise RuntimeError("SNOPT is not available in this Drake build")
    solver_options = SolverOptions()
    solver_options.SetOption(solver.solver_id(), "Major iterations limit", opts.major_iterations)
    best = None
    for mount0, q0 in guesses:
        mount0 = np.clip(mount0, opts.mount_lower, opts.mount_upper)
        prog.SetInitialGuess(m, mount0)
        prog.SetInitialGuess(Q, np.tile(q0, (n, 1)))
        result = solver.Solve(prog, None, solver_options)
        cost = result.get_optimal_cost()
        if np.isfinite(cost) and (best is None or cost < best[0]):
            best = (cost, result.GetSolution(m), result.GetSolution(Q), result.get_solver_details().info)
    return best


def pose_residuals(model: KinematicModel, mount: np.ndarray, q: np.ndarray, hand: HandTrajectory) -> tuple[np.ndarray, np.ndarray]:
    """Position (m) and tool-axis angle (rad) errors of the tool against the demonstrated poses."""
    pos, ang = np.empty(len(q)), np.empty(len(q))
    for i, qi in enumerate(q):
        X = model.tcp_pose(qi, mount)
        pos[i] = np.linalg.norm(X.translation() - hand.position[i])
        axis = X.rotation().matrix() @ model.tool_axis
        ang[i] = np.arccos(np.clip(axis @ hand.palm_axis[i], -1.0, 1.0))
    return pos, ang
