"""Joint trajectory for a sequence of full tool poses (position and orientation) by inverse kinematics.

Where :mod:`besdrake.embodiment.ik` matches a tool axis only (a tool that cannot turn like a wrist),
this module matches the whole tool pose, as a gripper needs. Each pose is one Drake
:class:`~pydrake.multibody.inverse_kinematics.InverseKinematics` program over the welded plant
(:func:`~besdrake.embodiment.kinematics.welded_plant`):

* the tool origin within ``position_tolerance`` of the target along each axis (a constraint) and
  pulled onto it by a ``PositionCost``;
* the tool orientation: within ``orientation_tolerance`` rad of the target (a constraint) when one
  is given, and always pulled towards it by an ``OrientationCost`` (weight on ``1 - cos angle``);
* a quadratic cost on the distance to the previous solution (no jumps between IK branches);
* the arm joints within their limits shrunk by ``joint_margin``; the gripper's joints (if the
  plant has any) bounded to the given opening; any other position (a finger that mimics a gripper
  joint: ``InverseKinematics`` adds the plant's coupler constraints) within its joint limits, free to
  follow. The tool pose depends on the arm joints only.

The first pose is solved from several starts; the forward pass runs from up to ``n_branches`` of its
distinct solutions (IK branches) until one gives a trajectory with every pose reached and no jump
(:func:`_first_poses`). A pose whose constraints cannot be met is solved again with the orientation as a cost only, then
with the position as a cost too; it is then reported unreachable with its residuals. A forward pass
(each pose seeded by the previous solution) is followed by a backward pass that removes the start-up
transient of the first pose, as in :func:`besdrake.embodiment.ik.ik_trajectory`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.inverse_kinematics import InverseKinematics
from pydrake.solvers import SnoptSolver

from besdrake.embodiment.ik import IKTrajectory
from besdrake.embodiment.kinematics import KinematicModel


@dataclass
class PoseIKOptions:
    """Tolerances and weights of the pose programs (SI units, rad)."""

    position_tolerance: float = 0.002  # m, per axis
    orientation_tolerance: float | None = None  # rad; None: orientation as a cost only
    orientation_weight: float = 10.0  # on (1 - cos angle)
    continuity_weight: float = 0.01  # per rad^2 of distance to the previous solution
    position_cost_weight: float = 1.0e4  # per m^2 (within the tolerance too: the target itself is sought)
    joint_margin: float = 0.05  # rad kept from every position limit
    backward_pass: bool = True
    n_starts: int = 8  # random starts for the first pose, besides the seed and the home pose
    n_branches: int = 3  # first-pose solutions tried as the start of a forward pass (the first without
    # unreachable poses and jumps is kept, else the one with the fewest, then the smallest largest step)


@dataclass
class PoseIKTrajectory(IKTrajectory):
    """:class:`~besdrake.embodiment.ik.IKTrajectory` for full poses: ``angle_residual`` is the rotation
    angle (rad) between the reached and the target tool orientation; ``reachable`` says the position
    (and, when a tolerance was given, the orientation) constraint was met."""

    orientation_tolerance: float | None = None

    def unreachable_report(self) -> list[dict]:
        """One entry per pose that could not be reached: index, time and both residuals."""
        return [
            {"index": int(i), "t": float(self.t[i]), "position_residual_m": float(self.position_residual[i]),
             "angle_residual_rad": float(self.angle_residual[i])}
            for i in np.flatnonzero(~self.reachable)
        ]


def _rotations(orientations: np.ndarray) -> list[RotationMatrix]:
    """Quaternions (n, 4; w, x, y, z) or rotation matrices (n, 3, 3) as Drake rotations."""
    arr = np.asarray(orientations, dtype=float)
    if arr.ndim == 2 and arr.shape[1] == 4:
        from pydrake.common.eigen_geometry import Quaternion

        return [RotationMatrix(Quaternion(q / np.linalg.norm(q))) for q in arr]
    if arr.ndim == 3 and arr.shape[1:] == (3, 3):
        return [RotationMatrix(m) for m in arr]
    raise ValueError(f"orientations must be quaternions (n, 4) or rotation matrices (n, 3, 3), got {arr.shape}")


class _PoseSolver:
    """Builds and solves the program of one pose on a welded plant (see the module docstring)."""

    def __init__(self, model: KinematicModel, gripper: np.ndarray | None, options: PoseIKOptions):
        if model.n_mount:
            raise ValueError("pose IK needs the welded plant (welded_plant(robot))")
        self.model, self.opt = model, options
        plant = model.plant
        limits = model.robot.position_limits
        self.arm = model.arm_indices
        self.lower = limits[:, 0] + options.joint_margin
        self.upper = limits[:, 1] - options.joint_margin
        # Bounds of all positions: the arm within its limits, the gripper's joints locked; any other
        # position (e.g. a finger that mimics a gripper joint: InverseKinematics adds the plant's coupler
        # constraints) within its joint limits, free to follow.
        locked = model.positions(np.zeros(len(self.arm)), gripper)
        self.x_lower = np.asarray(plant.GetPositionLowerLimits(), dtype=float).copy()
        self.x_upper = np.asarray(plant.GetPositionUpperLimits(), dtype=float).copy()
        g = model.gripper_indices
        self.x_lower[g], self.x_upper[g] = locked[g], locked[g]
        self.x_lower[self.arm], self.x_upper[self.arm] = self.lower, self.upper
        self.locked = np.clip(locked, self.x_lower, self.x_upper)
        self.solver = SnoptSolver()

    def solve(self, p: np.ndarray, R: RotationMatrix, anchor: np.ndarray, guesses: list[np.ndarray]) -> tuple[np.ndarray, bool]:
        """Arm joints for pose ``(p, R)``, pulled towards ``anchor``; tries each guess with the
        constraints, then the first with costs only. Returns the joints and whether the
        constraints were met."""
        opt = self.opt
        stages = [(True, opt.orientation_tolerance is not None, g) for g in guesses]
        if opt.orientation_tolerance is not None:
            stages += [(True, False, g) for g in guesses]
        stages.append((False, False, guesses[0]))
        for hard_position, hard_orientation, guess in stages:
            q, ok = self._program(p, R, anchor, guess, hard_position, hard_orientation)
            if ok:
                return q, hard_position and (hard_orientation or opt.orientation_tolerance is None)
        return q, False

    def _program(self, p, R, anchor, guess, hard_position: bool, hard_orientation: bool) -> tuple[np.ndarray, bool]:
        model, opt, plant = self.model, self.opt, self.model.plant
        ik = InverseKinematics(plant, with_joint_limits=False)
        x = ik.q()
        prog = ik.get_mutable_prog()
        prog.AddBoundingBoxConstraint(self.x_lower, self.x_upper, x)
        world = plant.world_frame()
        if hard_position:
            tol = opt.position_tolerance
            ik.AddPositionConstraint(model.tcp, np.zeros(3), world, p - tol, p + tol)
        ik.AddPositionCost(world, p, model.tcp, np.zeros(3), opt.position_cost_weight * np.eye(3))
        if hard_orientation:
            ik.AddOrientationConstraint(world, R, model.tcp, RotationMatrix(), opt.orientation_tolerance)
        ik.AddOrientationCost(world, R, model.tcp, RotationMatrix(), opt.orientation_weight)
        q_arm = x[self.arm]
        prog.AddQuadraticErrorCost(opt.continuity_weight * np.eye(len(self.arm)), anchor, q_arm)
        start = self.locked.copy()
        start[self.arm] = np.clip(guess, self.lower, self.upper)
        prog.SetInitialGuess(x, start)
        result = self.solver.Solve(prog)
        return result.GetSolution(x)[self.arm], result.is_success()


def pose_ik_trajectory(
    model: KinematicModel,
    t: np.ndarray,
    positions: np.ndarray,
    orientations: np.ndarray,
    q_seed: np.ndarray,
    gripper: np.ndarray | None = None,
    options: PoseIKOptions | None = None,
) -> PoseIKTrajectory:
    """Arm joints for every tool pose: ``positions`` (n, 3) m and ``orientations`` (quaternions (n, 4)
    w-first, or rotation matrices (n, 3, 3)) of the tool frame in the welded plant's world (the robot's
    base). ``q_seed`` (arm joints) seeds the first pose; ``gripper``: the gripper joints' positions
    held during the solve (default: the robot file's open position)."""
    opt = options or PoseIKOptions()
    positions = np.asarray(positions, dtype=float)
    t = np.asarray(t, dtype=float)
    rotations = _rotations(orientations)
    n = len(t)
    if positions.shape != (n, 3) or len(rotations) != n or n == 0:
        raise ValueError(f"need n >= 1 times, positions (n, 3) and n orientations; got {t.shape}, {positions.shape}, {len(rotations)}")
    if not (np.isfinite(positions).all() and np.isfinite(t).all()):
        raise ValueError("pose targets must be finite")
    solver = _PoseSolver(model, gripper, opt)
    seed = np.clip(np.asarray(q_seed, dtype=float), solver.lower, solver.upper)
    best = None
    for q0, ok0 in _first_poses(solver, model, positions[0], rotations[0], seed, opt)[: opt.n_branches]:
        q, ok = _forward(solver, positions, rotations, q0, ok0)
        trial = IKTrajectory(t, q, np.zeros(n), np.zeros(n), ok)
        key = (int((~ok).sum()), len(trial.jumps()), trial.max_joint_step)
        if best is None or key < best[0]:
            best = (key, q, ok)
        if key[:2] == (0, 0):
            break
    _, q, ok = best
    if opt.backward_pass:
        for i in range(n - 2, -1, -1):
            q_new, ok_new = solver.solve(positions[i], rotations[i], q[i + 1], [q[i + 1], q[i]])
            if ok_new or not ok[i]:  # never trade a reached pose for a missed one
                q[i], ok[i] = q_new, ok_new
    pos_res, ang_res = pose_residuals(model, q, positions, rotations)
    return PoseIKTrajectory(t=t, q=q, position_residual=pos_res, angle_residual=ang_res, reachable=ok,
                            orientation_tolerance=opt.orientation_tolerance)


def _forward(solver: _PoseSolver, positions: np.ndarray, rotations: list, q0: np.ndarray, ok0: bool):
    """Forward pass from the first pose's solution ``q0``: each pose from and towards the previous one."""
    q = np.empty((len(positions), len(q0)))
    ok = np.zeros(len(positions), dtype=bool)
    q[0], ok[0] = q0, ok0
    for i in range(1, len(positions)):
        q[i], ok[i] = solver.solve(positions[i], rotations[i], q[i - 1], [q[i - 1]])
    return q, ok


def _first_poses(solver: _PoseSolver, model: KinematicModel, p: np.ndarray, R: RotationMatrix, seed: np.ndarray,
                 opt: PoseIKOptions) -> list[tuple[np.ndarray, bool]]:
    """Distinct solutions of the first pose from several starts (the seed, the home pose, ``opt.n_starts``
    random poses within the limits, fixed random seed), best first: the branches a trajectory may
    follow. The seed itself comes first when it reaches the pose (within the position tolerance and
    0.01 rad): a trajectory that starts where the arm stands. Then best: reached, then the
    smallest orientation residual (in steps of 0.05 rad), then the farthest from the joint limits (the
    smallest distance of any joint to its limit, relative to its range: a wrist that starts mid-range
    can follow a turning hand without running into its stop and flipping)."""
    rng = np.random.default_rng(0)
    starts = [seed, np.clip(model.robot.home, solver.lower, solver.upper)]
    starts += list(rng.uniform(solver.lower, solver.upper, size=(opt.n_starts, len(seed))))
    found = []
    _, ang = pose_residuals(model, seed[None], p[None], [R])
    if np.linalg.norm(model.tcp_pose(seed).translation() - p) <= opt.position_tolerance and ang[0] <= 0.01:
        found.append(((False, -1, 0.0), seed.copy(), True))  # the seed is there already (e.g. the arm's pose)
    for start in starts:
        q, ok = solver.solve(p, R, seed, [start])
        _, ang = pose_residuals(model, q[None], p[None], [R])
        margin = np.min(np.minimum(q - solver.lower, solver.upper - q) / (solver.upper - solver.lower))
        if all(np.abs(q - other).max() > 0.1 for _, other, _ in found):
            found.append(((not ok, round(float(ang[0]) / 0.05), -float(margin)), q, ok))
    found.sort(key=lambda f: f[0])
    return [(q, ok) for _, q, ok in found]


def pose_residuals(model: KinematicModel, q: np.ndarray, positions: np.ndarray, rotations) -> tuple[np.ndarray, np.ndarray]:
    """Distance (m) and rotation angle (rad) from the tool pose of each ``q`` to its target."""
    rotations = rotations if isinstance(rotations, list) else _rotations(rotations)
    pos_res, ang_res = np.empty(len(q)), np.empty(len(q))
    for i, qi in enumerate(q):
        X: RigidTransform = model.tcp_pose(qi)
        pos_res[i] = np.linalg.norm(X.translation() - positions[i])
        ang_res[i] = (rotations[i].inverse() @ X.rotation()).ToAngleAxis().angle()
    return pos_res, ang_res
