"""The gripper command of a pick-and-place motion plan.

A :class:`~besdrake.plan.MotionPlan` carries the arm's joints; the gripper's command travels in its ``meta``:
``plan.meta["gripper"] = {"t": [t0, t1, ...], "width": [w0, w1, ...]}``: the commanded distance (m) between
the fingers' pads at those plan times (s), linearly interpolated, held before the first and after the last
sample. It is JSON data, so it is saved and loaded with the plan. A plan without it keeps the gripper open.

A parallel gripper's joints each move half the width (each joint's position is its pad's distance from the
gripper's axis). The command is clipped into the robot's [closed, open] range: a "closed" command (width 0 on a
box) squeezes the box with the gripper's effort limit, its grip force.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from besdrake.plan import MotionPlan, PlanError
from besdrake.robot import Robot


@dataclass(frozen=True)
class GripperCommand:
    """Commanded pad distance ``width`` (m) at plan times ``t`` (s)."""

    t: np.ndarray
    width: np.ndarray

    @classmethod
    def of(cls, plan: MotionPlan, robot: Robot) -> "GripperCommand":
        """The plan's gripper command (``meta["gripper"]``), or the gripper held open when the plan has none."""
        g = robot.end_effector.gripper
        if g is None:
            raise PlanError(f"robot {robot.name!r} has no gripper")
        spec = plan.meta.get("gripper")
        if spec is None:
            return cls(np.array([0.0]), np.array([open_width(robot)]))
        if not isinstance(spec, dict) or "t" not in spec or "width" not in spec:
            raise PlanError('plan meta "gripper" must be {"t": [...], "width": [...]}')
        try:
            t, w = np.asarray(spec["t"], dtype=float), np.asarray(spec["width"], dtype=float)
        except (TypeError, ValueError) as err:
            raise PlanError(f'plan meta "gripper" is not numeric: {err}') from err
        if t.ndim != 1 or t.shape != w.shape or t.size == 0:
            raise PlanError(f'plan meta "gripper": "t" and "width" must be equally long lists, got {t.shape} and {w.shape}')
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(w))) or np.any(np.diff(t) <= 0):
            raise PlanError('plan meta "gripper": times must be finite and increase strictly, widths finite')
        return cls(t, w)

    def to_meta(self) -> dict:
        return {"t": self.t.tolist(), "width": self.width.tolist()}

    def joint_positions(self, robot: Robot, width: np.ndarray) -> np.ndarray:
        """(len(width), n_gripper_joints) joint positions for ``width``: half of it each, clipped into [closed, open]."""
        g = robot.end_effector.gripper
        lo, hi = np.minimum(g.open, g.closed), np.maximum(g.open, g.closed)
        return np.clip(np.outer(np.asarray(width, dtype=float) / 2.0, np.ones(len(g.joints))), lo, hi)

    def trajectory(self, robot: Robot, time_shift: float = 0.0):
        """The joint-position command as a Drake ``PiecewisePolynomial`` (first-order hold)."""
        from pydrake.trajectories import PiecewisePolynomial

        q = self.joint_positions(robot, self.width)
        if self.t.size == 1:
            return PiecewisePolynomial(q[0][:, None])
        return PiecewisePolynomial.FirstOrderHold(self.t + time_shift, q.T)

    def sample(self, times: np.ndarray) -> np.ndarray:
        """Commanded width (m) at ``times``."""
        return np.interp(times, self.t, self.width)

    def closed_time(self) -> float | None:
        """The first time (s) the command reaches its narrowest width after it started closing (None: it never closes)."""
        w = self.width
        closing = np.nonzero(np.diff(w) < 0)[0]
        if closing.size == 0:
            return None
        after = np.arange(closing[0] + 1, len(w))
        return float(self.t[after[np.argmin(w[after])]])

    def release_time(self) -> float | None:
        """The first time (s) the command opens after it has closed (None: never closed, or never reopened)."""
        w = self.width
        closing = np.nonzero(np.diff(w) < 0)[0]
        if closing.size == 0:
            return None
        opening = np.nonzero(np.diff(w[closing[0]:]) > 0)[0]
        return None if opening.size == 0 else float(self.t[closing[0] + opening[0]])


def open_width(robot: Robot) -> float:
    """Pad distance (m) of the open gripper."""
    return float(2.0 * np.max(robot.end_effector.gripper.open))
