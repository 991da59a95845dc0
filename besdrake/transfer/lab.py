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

from besdrake.plan import MotionPlan, PlanError
from besdrake.robot import JointLimits
from besdrake.transfer.measurement import Measurement
from besdrake.transfer.safety import SafetyLimits


@runtime_checkable
class Lab(Protocol):
    """Anything that runs motion plans and measures what happened.

    ``execute(plan, trial=None)``: run ``plan`` and return its :class:`Measurement`. ``trial`` is the
    index the measurement gets (0, 1, 2, ... in execution order); when None the lab counts itself.
    A lab whose measurements are random must make trial ``k`` reproducible (resuming a run re-executes
    the trial that was interrupted). ``description()`` returns the public facts written into a log.
    A lab's ``robot`` (a :class:`~besdrake.robot.Robot` read from its robot file) gives the safety gate its
    limits; a lab without one needs the gate's ``limits=``. A lab whose measurements are a task's subclass of
    :class:`Measurement` names it as ``measurement_type`` (the gate's refusals and the log use it).
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


def _default_measurement_type() -> type[Measurement]:
    from besdrake.task import DEFAULT_TASK, get_task

    return get_task(DEFAULT_TASK).measurement_type()


class SafetyGate(TrialCounter):
    """Wraps any :class:`Lab`: refuses a plan that would exceed a joint position, velocity or acceleration
    limit *before* it reaches the lab.

    A refused plan gives a Measurement with ``flags["refused_by_safety_gate"]`` and the violations (joint,
    kind, amount beyond the limit) in ``message``; a malformed plan (NaN, wrong shape, time not increasing)
    is refused the same way. The check is :meth:`MotionPlan.check_limits` on the interpolated plan, i.e.
    on what the controller would be sent. ``resolution`` (s) is its sampling step. The limits are the
    robot's (``lab.robot``, read from its robot file) unless ``limits`` are given. ``safety``
    (:class:`SafetyLimits`, by default the robot file's ``safety`` section) refuses too long plans, too close
    knots and a start away from the lab's ``current_pose()`` (when the lab has that method and it returns a pose).
    """

    def __init__(self, lab: Lab, limits: JointLimits | None = None, resolution: float = 0.002, safety: SafetyLimits | None = None) -> None:
        if not hasattr(lab, "execute"):
            raise TypeError(f"SafetyGate needs a lab with an execute(plan) method, got {type(lab).__name__}")
        self.lab = lab
        self.robot = getattr(lab, "robot", None)
        self.limits = limits or _robot_limits(lab)
        self.safety = safety or (SafetyLimits.of(self.robot) if self.robot is not None else SafetyLimits())
        self.resolution = float(resolution)
        self.name = f"{getattr(lab, 'name', type(lab).__name__)}"
        self.refused = 0
        #: The Measurement class of the wrapped lab (its ``measurement_type``; a refused plan is logged as one); a lab
        #: that names none is taken for the default task's (what a version-1 log holds).
        self.measurement_type = getattr(lab, "measurement_type", None) or _default_measurement_type()

    def check(self, plan: MotionPlan) -> list[str]:
        """The reasons to refuse ``plan`` (empty when it may run)."""
        if not isinstance(plan, MotionPlan):
            return [f"not a MotionPlan: {type(plan).__name__}"]
        pose = getattr(self.lab, "current_pose", None)
        timing = self.safety.problems(plan, pose() if callable(pose) else None)
        if timing:
            return timing  # before sampling the limits: a too long plan would take that long to check
        try:
            report = plan.check_limits(self.limits, resolution=self.resolution)
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
            return self.measurement_type(
                trial=trial,
                plan=plan,
                flags={"refused_by_safety_gate": True},
                message="refused by the safety gate: " + "; ".join(reasons),
                meta={"lab": self.name, "plan_name": plan.meta.get("name", "")},
            )
        return self.lab.execute(plan, trial=trial)


def _robot_limits(lab) -> JointLimits:
    robot = getattr(lab, "robot", None)
    if robot is None:
        raise TypeError(f"SafetyGate needs limits= (a robot's JointLimits) or a lab with a robot; {type(lab).__name__} has none")
    return robot.limits


__all__ = ["JointLimits", "Lab", "SafetyGate", "SafetyLimits", "TrialCounter"]
