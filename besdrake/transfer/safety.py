"""Timing and start checks of a motion plan before it runs, besides the joint limits: the one place of
their defaults (used by :class:`besdrake.transfer.lab.SafetyGate` and ``besdrake simulate``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from besdrake.plan import MotionPlan


@dataclass(frozen=True)
class SafetyLimits:
    """Checks of a plan's timing and start that the gate makes besides the joint limits (the one place of
    their defaults):

    * ``max_duration_s``: the longest plan the robot may run (a skill takes seconds; an hour-long plan would
      hang the lab and the simulation);
    * ``min_knot_spacing_s``: knots closer than this are no motion a controller can follow (set it to your
      controller's period; the default 0.1 ms stays below the 0.54 ms last knot step of imitated plans);
    * ``start_tolerance_rad``: the plan's first pose may differ from the pose the robot stands at (the lab's
      ``current_pose()``: its home/rest pose or the last commanded end pose) by at most this much per joint.
    """

    max_duration_s: float = 30.0
    min_knot_spacing_s: float = 1e-4
    start_tolerance_rad: float = 0.05

    @classmethod
    def of(cls, robot) -> "SafetyLimits":
        """The checks of ``robot``'s file (its ``safety`` section)."""
        s = robot.safety
        return cls(max_duration_s=s.max_plan_duration, min_knot_spacing_s=s.min_knot_spacing, start_tolerance_rad=s.start_tolerance)

    def __post_init__(self) -> None:
        for name in ("max_duration_s", "min_knot_spacing_s", "start_tolerance_rad"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValueError(f"SafetyLimits.{name} must be a positive number, got {v!r}")

    def problems(self, plan: MotionPlan, current_pose: np.ndarray | None = None) -> list[str]:
        """The reasons to refuse ``plan`` on timing or start (empty when none); ``current_pose`` None skips
        the start check. Used by the gate and by ``besdrake simulate``."""
        t = np.asarray(plan.t, dtype=float)
        out = []
        if t.size and np.isfinite(t[-1]) and t[-1] > self.max_duration_s:
            out.append(f"plan lasts {t[-1]:g} s, longer than the maximum {self.max_duration_s:g} s")
        if t.size > 1:
            step = float(np.min(np.diff(t)))
            if np.isfinite(step) and step < self.min_knot_spacing_s:
                k = int(np.argmin(np.diff(t)))
                out.append(f"knots {k} and {k + 1} are {step:.3g} s apart, closer than the control period {self.min_knot_spacing_s:g} s")
        if current_pose is not None and np.shape(plan.q) and len(plan.q):
            q0 = np.asarray(plan.q, dtype=float)[0]
            cur = np.asarray(current_pose, dtype=float)
            if q0.shape == cur.shape:
                off = np.abs(q0 - cur)
                j = int(np.argmax(off))
                if off[j] > self.start_tolerance_rad:
                    out.append(f"plan starts {off[j]:.3g} rad from the robot's current pose at joint {j + 1} "
                               f"(tolerance {self.start_tolerance_rad:g} rad): move the robot to the start first")
        return out


__all__ = ["SafetyLimits"]
