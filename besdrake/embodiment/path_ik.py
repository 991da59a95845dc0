"""Joint path along a tool pose path by resolved-rate (differential) inverse kinematics.

:mod:`besdrake.embodiment.pose_ik` solves one nonlinear program per pose: accurate, but each pose may
land anywhere on a redundant arm's self-motion manifold, so a 7-joint arm's elbow can swing between
samples (seen on the iiwa: 20-40 rad/s peaks on the redundant joints of a demonstrated hand path, time scaling
factors of 6-26). Here the path is *followed* instead: from a start configuration, each sample's joint
step is the damped least-squares solution of the tool's 6-D pose error (Drake's spatial Jacobian of the
tool frame), so the joints move continuously and by the least the pose change needs; the remaining
freedom (the null space) pulls gently towards a rest posture and away from the joint limits.

Per sample, up to ``iterations`` Newton steps ``dq = W J^T (J W J^T + lambda^2 I)^-1 e + N k (q_rest - q)``
with the pose error ``e = [orientation_length * angle-axis error, position error]`` (the angular rows
scaled to metres), ``N`` the null-space projector, each step clipped to ``max_step`` rad and the joints
to their limits shrunk by ``joint_margin``. The damping grows as the weighted Jacobian's smallest singular value falls below ``singular_zone``
(Maciejewski and Klein's rule), where the tool then lags its target rather than the joints racing: the residuals say by how much.
About 30 us per Jacobian: a 400-pose path costs tens of milliseconds, cheap enough for every candidate of
a policy search.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.math import RotationMatrix
from pydrake.multibody.tree import JacobianWrtVariable

from besdrake.embodiment.kinematics import KinematicModel
from besdrake.embodiment.pose_ik import PoseIKTrajectory, _rotations


@dataclass
class PathIKOptions:
    """Gains and tolerances of the resolved-rate path follower (SI units, rad)."""

    iterations: int = 4              # Newton steps per sample (fewer when the error is below the tolerances)
    position_tolerance: float = 0.002  # m: a pose within this and angle_tolerance is reached
    angle_tolerance: float = 0.05    # rad
    orientation_length: float = 0.2  # m per rad: weight of the orientation rows against the position rows
    damping_max: float = 0.02        # lambda at a singularity (none while the smallest singular value >= singular_zone)
    singular_zone: float = 0.01      # m: smallest singular value of the weighted Jacobian below which damping rises
    posture_gain: float = 0.05       # fraction of the distance to the rest posture closed per sample, in the null space
    limit_gain: float = 0.1          # push away from a limit within limit_zone of it, in the null space
    limit_zone: float = 0.3          # rad
    joint_margin: float = 0.02       # rad kept from every position limit
    max_step: float = 0.2            # rad per Newton step and joint


class PathIK:
    """A resolved-rate follower of tool pose paths on ``model`` (the robot's :func:`welded_plant`)."""

    def __init__(self, model: KinematicModel, options: PathIKOptions | None = None,
                 rest: np.ndarray | None = None) -> None:
        if model.n_mount:
            raise ValueError("path IK needs the welded plant (welded_plant(robot))")
        self.model, self.opt = model, options or PathIKOptions()
        limits = model.robot.position_limits
        self.lower = limits[:, 0] + self.opt.joint_margin
        self.upper = limits[:, 1] - self.opt.joint_margin
        self.rest = np.asarray(model.robot.home if rest is None else rest, dtype=float)
        self.arm = model.arm_indices
        self._w = np.concatenate([np.full(3, self.opt.orientation_length), np.ones(3)])

    def pose_and_jacobian(self, q: np.ndarray):
        """Tool pose and the weighted 6 x n Jacobian (angular rows first, scaled to metres) at ``q``."""
        m = self.model
        X = m.tcp_pose(q)  # sets the context's positions
        J = m.plant.CalcJacobianSpatialVelocity(m.context, JacobianWrtVariable.kQDot, m.tcp, np.zeros(3),
                                                m.plant.world_frame(), m.plant.world_frame())
        return X, self._w[:, None] * J[:, self.arm]

    def error(self, X, p: np.ndarray, R: RotationMatrix) -> np.ndarray:
        """Weighted pose error (6,): angle-axis of ``R X.R^T`` (world) times orientation_length, then position."""
        aa = (R @ X.rotation().inverse()).ToAngleAxis()
        return self._w * np.concatenate([aa.axis() * aa.angle(), p - X.translation()])

    def step(self, q: np.ndarray, e: np.ndarray, J: np.ndarray) -> np.ndarray:
        """One damped least-squares step with the null-space posture and limit terms. A joint at a limit that the
        step would push further is locked (its column removed) and the step solved again (a clamping loop), so a
        pose out of reach leaves the tool lagging rather than the free joints racing."""
        opt = self.opt
        to_lower, to_upper = q - self.lower, self.upper - q
        push = np.where(to_lower < opt.limit_zone, opt.limit_zone - to_lower, 0.0) - np.where(
            to_upper < opt.limit_zone, opt.limit_zone - to_upper, 0.0)
        bias = opt.posture_gain * (self.rest - q) + opt.limit_gain * push
        free = np.ones(len(q), dtype=bool)
        for _ in range(len(q)):
            dq = np.zeros(len(q))
            dq[free] = self._dls(J[:, free], e, bias[free])
            blocked = free & (((q + dq) < self.lower) & (dq < 0) | ((q + dq) > self.upper) & (dq > 0))
            if not blocked.any():
                break
            free &= ~blocked
            if not free.any():
                return np.zeros(len(q))
        return np.clip(dq, -opt.max_step, opt.max_step)

    def _dls(self, J: np.ndarray, e: np.ndarray, bias: np.ndarray) -> np.ndarray:
        """Damped least-squares solution of ``J dq = e`` plus ``bias`` projected into ``J``'s null space."""
        opt = self.opt
        sigma_min = np.linalg.svd(J, compute_uv=False)[-1] if J.shape[1] >= 6 else 0.0
        lam2 = 0.0 if sigma_min >= opt.singular_zone else (1 - (sigma_min / opt.singular_zone) ** 2) * opt.damping_max**2
        J_pinv = J.T @ np.linalg.inv(J @ J.T + (lam2 + 1e-9) * np.eye(6))
        return J_pinv @ e + (np.eye(J.shape[1]) - J_pinv @ J) @ bias

    def solve_pose(self, q: np.ndarray, p: np.ndarray, R: RotationMatrix) -> tuple[np.ndarray, float, float]:
        """Newton steps from ``q`` towards pose ``(p, R)``; returns joints, position and angle residuals."""
        opt = self.opt
        for _ in range(opt.iterations):
            X, J = self.pose_and_jacobian(q)
            e = self.error(X, p, R)
            pos_err, ang_err = np.linalg.norm(e[3:]), np.linalg.norm(e[:3]) / opt.orientation_length
            if pos_err <= 0.2 * opt.position_tolerance and ang_err <= 0.2 * opt.angle_tolerance:
                return q, pos_err, ang_err
            q = np.clip(q + self.step(q, e, J), self.lower, self.upper)
        X = self.model.tcp_pose(q)
        e = self.error(X, p, R)
        return q, float(np.linalg.norm(e[3:])), float(np.linalg.norm(e[:3]) / opt.orientation_length)

    def follow(self, t: np.ndarray, positions: np.ndarray, orientations, q_start: np.ndarray) -> PoseIKTrajectory:
        """Joints for every pose of the path, starting from ``q_start`` (where the arm stands). ``orientations``:
        quaternions (n, 4; w first) or rotation matrices (n, 3, 3). The first pose is approached from ``q_start``
        by up to 10 x ``iterations`` Newton steps."""
        t, positions = np.asarray(t, dtype=float), np.asarray(positions, dtype=float)
        rotations = _rotations(orientations)
        n = len(t)
        if positions.shape != (n, 3) or len(rotations) != n or n == 0:
            raise ValueError(f"need n >= 1 times, positions (n, 3) and n orientations; got {t.shape}, "
                             f"{positions.shape}, {len(rotations)}")
        if not (np.isfinite(positions).all() and np.isfinite(t).all()):
            raise ValueError("pose targets must be finite")
        q = np.clip(np.asarray(q_start, dtype=float), self.lower, self.upper)
        for _ in range(10):
            q, pos_err, ang_err = self.solve_pose(q, positions[0], rotations[0])
            if pos_err <= 0.2 * self.opt.position_tolerance and ang_err <= 0.2 * self.opt.angle_tolerance:
                break
        out = np.empty((n, len(q)))
        pos_res, ang_res = np.empty(n), np.empty(n)
        for i in range(n):
            q, pos_res[i], ang_res[i] = self.solve_pose(q, positions[i], rotations[i])
            out[i] = q
        ok = (pos_res <= self.opt.position_tolerance) & (ang_res <= self.opt.angle_tolerance)
        return PoseIKTrajectory(t=t, q=out, position_residual=pos_res, angle_residual=ang_res, reachable=ok,
                                orientation_tolerance=self.opt.angle_tolerance)
