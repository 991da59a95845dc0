"""Joint trajectory of a demonstrated segment by inverse kinematics in the robot's base frame.

With the synchronization frame fixed, every demonstrated hand pose (at the recording's full
rate) is solved with Drake's :class:`~pydrake.multibody.inverse_kinematics.InverseKinematics`:
the tool origin within ``position_tolerance`` of the hand centre (a constraint), the robot file's
tool axis towards the palm normal (a cost: a rigid tool cannot turn like a wrist, so the
angle is matched as well as the arm allows and reported), and a cost on the distance to the previous
solution so that consecutive configurations stay close (no jumps between IK branches). A pose
whose position constraint cannot be met is solved again with the position as a cost and
reported as unreachable with its residual.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.math import RigidTransform
from pydrake.multibody.inverse_kinematics import InverseKinematics
from pydrake.solvers import SnoptSolver

from besdrake.embodiment.kinematics import KinematicModel


@dataclass
class IKTrajectory:
    """Joint positions for every demonstrated pose and how well they reproduce it."""

    t: np.ndarray  # (n,) s
    q: np.ndarray  # (n, joints) rad
    position_residual: np.ndarray  # (n,) m
    angle_residual: np.ndarray  # (n,) rad
    reachable: np.ndarray  # (n,) bool: position constraint met

    def jumps(self, ratio: float = 4.0, floor: float = 0.3) -> list[tuple[int, int, float]]:
        """Discontinuities: ``(sample, joint, step)`` where a joint moves more than ``floor`` rad and
        more than ``ratio`` times the larger of its neighbouring steps. A fast but smooth motion
        has similar consecutive steps; a switch between IK branches has one step far larger than
        its neighbours (typically around pi), whatever the sample rate. Smaller kinks (seen: up
        to 0.14 rad where a joint rides its margin to a limit) are smoothed by the DMP and are
        not the large configuration changes the paper warns about."""
        steps = np.abs(np.diff(self.q, axis=0))
        if len(steps) < 2:
            return []
        padded = np.vstack([steps[:1] * 0, steps, steps[:1] * 0])
        neighbour = np.maximum(padded[:-2], padded[2:])
        mask = (steps > floor) & (steps > ratio * neighbour)
        return [(int(i), int(j), float(steps[i, j])) for i, j in zip(*np.nonzero(mask))]

    @property
    def max_joint_step(self) -> float:
        """Largest change of any joint between consecutive samples (rad): a jump detector."""
        return float(np.abs(np.diff(self.q, axis=0)).max()) if len(self.q) > 1 else 0.0

    def unreachable_report(self) -> list[dict]:
        """One entry per pose that could not be reached: index, time and residual."""
        return [
            {"index": int(i), "t": float(self.t[i]), "position_residual_m": float(self.position_residual[i])}
            for i in np.flatnonzero(~self.reachable)
        ]


def ik_trajectory(
    model: KinematicModel,
    t: np.ndarray,
    positions: np.ndarray,
    axes: np.ndarray,
    q_guess: np.ndarray,
    position_tolerance: float = 0.0005,
    angle_weight: float = 10.0,
    continuity_weight: float = 1.0,
    joint_margin: float = 0.05,
) -> IKTrajectory:
    """Solve every pose (positions ``(n, 3)`` and palm axes ``(n, 3)`` in the base frame).

    ``q_guess`` ``(n, joints)`` seeds each solve (e.g. the synchronization program's solution
    interpolated to ``t``); each solve is pulled towards the previous solution.
    """
    if model.n_mount:
        raise ValueError("ik_trajectory needs the welded plant (welded_plant(robot))")
    plant, robot, tool_axis = model.plant, model.robot, model.tool_axis
    if plant.num_positions() != robot.n_joints:
        raise ValueError(f"ik_trajectory solves the arm's {robot.n_joints} joints; the plant has {plant.num_positions()} positions")
    n = len(t)
    lower = robot.position_limits[:, 0] + joint_margin
    upper = robot.position_limits[:, 1] - joint_margin
    solver = SnoptSolver()

    def solve(i: int, anchor: np.ndarray, *guesses: np.ndarray) -> tuple[np.ndarray, bool]:
        """Pose ``i`` pulled towards ``anchor``: the position as a constraint from each guess in
        turn, and as a cost (unreachable) only when no guess satisfies it."""
        for hard, guess in [(True, g) for g in guesses] + [(False, guesses[0])]:
            ik = InverseKinematics(plant, with_joint_limits=False)
            q = ik.q()
            prog = ik.get_mutable_prog()
            prog.AddBoundingBoxConstraint(lower, upper, q)
            if hard:
                ik.AddPositionConstraint(
                    model.tcp, np.zeros(3), plant.world_frame(),
                    positions[i] - position_tolerance, positions[i] + position_tolerance,
                )
            else:
                ik.AddPositionCost(plant.world_frame(), positions[i], model.tcp, np.zeros(3), 1.0e4 * np.eye(3))
            ik.AddAngleBetweenVectorsCost(plant.world_frame(), axes[i], model.tcp, tool_axis, angle_weight)
            prog.AddQuadraticErrorCost(continuity_weight * np.eye(robot.n_joints), anchor, q)
            prog.SetInitialGuess(q, guess)
            result = solver.Solve(prog)
            if result.is_success() or not hard:
                break
        return result.GetSolution(q), hard and result.is_success()

    q_out = np.empty((n, robot.n_joints))
    reachable = np.ones(n, dtype=bool)
    # Forward pass, each pose pulled towards the previous solution; then a backward pass pulls
    # each pose towards its successor, starting from it, which removes the start-up transient of
    # the first pose (solved from a mere guess, it can land in a worse local optimum).
    prev = np.clip(q_guess[0], lower, upper)
    for i in range(n):
        q_out[i], reachable[i] = solve(i, prev, prev if i else np.clip(q_guess[0], lower, upper))
        prev = q_out[i]
    for i in range(n - 2, -1, -1):
        q_new, ok = solve(i, q_out[i + 1], q_out[i + 1], q_out[i])
        if ok or not reachable[i]:  # never trade a reached pose for a missed one
            q_out[i], reachable[i] = q_new, ok
    pos_res = np.empty(n)
    ang_res = np.empty(n)
    for i in range(n):
        X: RigidTransform = model.tcp_pose(q_out[i])
        pos_res[i] = np.linalg.norm(X.translation() - positions[i])
        axis = X.rotation().matrix() @ tool_axis
        ang_res[i] = np.arccos(np.clip(axis @ axes[i], -1.0, 1.0))
    return IKTrajectory(t=np.asarray(t, float), q=q_out, position_residual=pos_res, angle_residual=ang_res, reachable=reachable)
