"""The lab interface (the seam where a real robot plugs in) and the safety gate in front of every lab.

A lab executes a :class:`~besdrake.plan.MotionPlan` and returns a
:class:`~besdrake.transfer.measurement.Measurement`::

    lab = SafetyGate(VirtualLab(load_lab_config("diagrams/labs/default_lab.yaml")))
    m = lab.execute(plan)          # trial numbers count up from 0 (or pass trial=k explicitly)

A real robot only has to implement :class:`Lab`: a ``name`` and ``execute(plan, trial=None)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from besdrake import robot
from besdrake.plan import MotionPlan, PlanError
from besdrake.transfer.measurement import Measurement
from besdrake.transfer.safety import SafetyLimits


@runtime_checkable
class Lab(Protocol):
    """Anything that runs motion plans and measures what happened.

    ``execute(plan, trial=None)``: run ``plan`` and return its :class:`Measurement`. ``trial`` is the
    index the measurement gets (0, 1, 2, ... in execution order); when None the lab counts itself.
    A lab whose measurements are random must make trial ``k`` reproducible (resuming a run re-executes
    the trial that was interrupted). ``description()`` returns the public facts written into a log.
    """

    name: str

    def execute(self, plan: MotionPlan, trial: int | None = None) -> Measurement: ...

    def description(self) -> dict: ...


class TrialCounter:
    """Mixin: ``next_trial(trial)`` returns ``trial`` (and continues counting after it) or the next index."""

    _next: int = 0

    def next_trial(self, trial: int | None) -> int:
        if trial is None:
            trial = self._next
        if isinstance(trial, bool) or not isinstance(trial, (int, np.integer)) or trial < 0:
            raise ValueError(f"trial must be a non-negative integer, got {trial!r}")
        self._next = int(trial) + 1
        return int(trial)


@dataclass(frozen=True)
class JointLimits:
    """Joint limits the gate enforces: ``position`` (6, 2) rad, ``velocity`` (6,) rad/s, ``acceleration`` (6,) rad/s^2.

    Defaults are COMPI's (:mod:`besdrake.robot`)."""

    position: np.ndarray = field(default_factory=lambda: robot.POSITION_LIMITS.copy())
    velocity: np.ndarray = field(default_factory=lambda: robot.VELOCITY_LIMITS.copy())
    acceleration: np.ndarray = field(default_factory=lambda: robot.ACCELERATION_LIMITS.copy())

    def __post_init__(self) -> None:
        for name, shape in (("position", (6, 2)), ("velocity", (6,)), ("acceleration", (6,))):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != shape or not np.all(np.isfinite(a)):
                raise ValueError(f"JointLimits.{name} must be finite with shape {shape}, got {a.shape}")
            object.__setattr__(self, name, a)
        if np.any(self.position[:, 0] >= self.position[:, 1]):
            raise ValueError("JointLimits.position: every lower limit must be below its upper limit")
        if np.any(self.velocity <= 0) or np.any(self.acceleration <= 0):
            raise ValueError("JointLimits: velocity and acceleration limits must be positive")


class SafetyGate(TrialCounter):
    """Wraps any :class:`Lab`: refuses a plan that would exceed a joint position, velocity or acceleration
    limit *before* it reaches the lab.

    A refused plan gives a Measurement with ``flags["refused_by_safety_gate"]`` and the violations (joint,
    kind, amount beyond the limit) in ``message``; a malformed plan (NaN, wrong shape, time not increasing)
    is refused the same way. The check is :meth:`MotionPlan.check_limits` on the interpolated plan, i.e.
    on what the controller would be sent. ``resolution`` (s) is its sampling step. ``safety``
    (:class:`SafetyLimits`) refuses too long plans, too close knots and a start away from the lab's
    ``current_pose()`` (when the lab has that method and it returns a pose).
    """

    def __init__(self, lab: Lab, limits: JointLimits | None = None, resolution: float = 0.002, safety: SafetyLimits | None = None) -> None:
        if not hasattr(lab, "execute"):
            raise TypeError(f"SafetyGate needs a lab with an execute(plan) method, got {type(lab).__name__}")
        self.lab = lab
        self.limits = limits or JointLimits()
        self.safety = safety or SafetyLimits()
        self.resolution = float(resolution)
        self.name = f"{getattr(lab, 'name', type(lab).__name__)}"
        self.refused = 0

    def check(self, plan: MotionPlan) -> list[str]:
        """The reasons to refuse ``plan`` (empty when it may run)."""
        if not isinstance(plan, MotionPlan):
            return [f"not a MotionPlan: {type(plan).__name__}"]
        pose = getattr(self.lab, "current_pose", None)
        timing = self.safety.problems(plan, pose() if callable(pose) else None)
        if timing:
            return timing  # before sampling the limits: a too long plan would take that long to check
        try:
            report = plan.check_limits(self.limits.position, self.limits.velocity, self.limits.acceleration, resolution=self.resolution)
        except PlanError as err:
            return [f"malformed plan: {err}"]
        return report.violations()

    def description(self) -> dict:
        d = dict(self.lab.description()) if hasattr(self.lab, "description") else {"name": self.name}
        d["safety_gate"] = {
            "position_limits_rad": self.limits.position.tolist(),
            "velocity_limits_rad_s": self.limits.velocity.tolist(),
            "acceleration_limits_rad_s2": self.limits.acceleration.tolist(),
            "max_duration_s": self.safety.max_duration_s,
            "min_knot_spacing_s": self.safety.min_knot_spacing_s,
            "start_tolerance_rad": self.safety.start_tolerance_rad,
        }
        return d

    def execute(self, plan: MotionPlan, trial: int | None = None) -> Measurement:
        """Refuse ``plan`` (see the class docstring) or pass it on to the wrapped lab as trial ``trial``."""
        trial = self.next_trial(trial)
        reasons = self.check(plan)
        if reasons:
            self.refused += 1
            if not isinstance(plan, MotionPlan):
                raise TypeError(f"SafetyGate.execute needs a MotionPlan, got {type(plan).__name__}")
            return Measurement(
                trial=trial,
                plan=plan,
                flags={"refused_by_safety_gate": True},
                message="refused by the safety gate: " + "; ".join(reasons),
                meta={"lab": self.name, "plan_name": plan.meta.get("name", "")},
            )
        return self.lab.execute(plan, trial=trial)


__all__ = ["JointLimits", "Lab", "SafetyGate", "SafetyLimits", "TrialCounter"]
