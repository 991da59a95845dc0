"""What a lab measures for one pick-and-place trial: :class:`PickPlaceMeasurement`.

A :class:`~besdrake.transfer.measurement.Measurement` (trial, plan, encoder log, flags, message, meta) plus what a
pick-and-place lab observes: the box's final pose from a camera or motion capture (bottom centre, m; roll, pitch,
yaw, rad; world frame), the place error and tilt computed from it, how high the box rose above the shelf and how far
it moved in the gripper while carried (box tracking), the first arm-fixture contact (a contact sensor or the
operator), and a summary of the encoder log (per joint: largest and RMS |measured - commanded|, rad). It never holds
a virtual lab's hidden effects.

Flags (besides the general ``refused_by_safety_gate``, ``joint_limit_exceeded``, ``aborted``): the failures of
:mod:`besdrake.tasks.pick_and_place.outcome` judged from the measured values (``not_lifted``, ``slipped``,
``dropped``, ``not_upright``, ``missed_place``, ``arm_fixture_collision``). ``success`` is True only for a trial
that ran and raised none.

In a log (format version 2, ``task: pick_and_place``) trials.csv's summary columns are :data:`SUMMARY`;
measurement.json holds ``result`` (:meth:`PickPlaceMeasurement.result_dict`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from besdrake.transfer.measurement import Measurement, MeasurementError

#: trials.csv columns of a pick-and-place log between plan_hash and flags.
SUMMARY = ("success", "place_error", "tilt", "box_x", "box_y", "box_z", "box_yaw")
#: The boolean results (what the lab judged) and the optional numbers (None: not measured).
BOOLEANS = ("success", "grasped", "lifted", "held", "upright", "on_table")
NUMBERS = ("place_error", "tilt", "lift", "slip")


def _opt_float(x: Any, name: str) -> float | None:
    if x is None:
        return None
    if isinstance(x, bool) or not isinstance(x, (int, float, np.floating, np.integer)) or not np.isfinite(x):
        raise MeasurementError(f"measurement field {name!r} must be a finite number or null, got {x!r}")
    return float(x)


def _opt_vector(x: Any, name: str, n: int | None) -> np.ndarray | None:
    if x is None:
        return None
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as err:
        raise MeasurementError(f"measurement field {name!r} is not numeric: {err}") from err
    if a.ndim != 1 or (n is not None and a.shape != (n,)) or not np.all(np.isfinite(a)):
        raise MeasurementError(f"measurement field {name!r} must be {n or 'n'} finite numbers, got {x!r}")
    return a


@dataclass
class PickPlaceMeasurement(Measurement):
    """One pick-and-place trial as a lab measured it (module docstring; SI units, world frame)."""

    TASK: ClassVar[str | None] = "pick_and_place"
    SUMMARY_COLUMNS: ClassVar[tuple[str, ...]] = SUMMARY

    success: bool = False
    grasped: bool = False            # the fingers stopped short of their closed command (gripper encoders)
    lifted: bool = False             # the box rose ``lift_clearance`` above the shelf
    held: bool = False               # it moved less than ``slip_tolerance`` in the gripper until released
    upright: bool = False
    on_table: bool = False
    place_error: float | None = None  # m, horizontal, measured box bottom centre to the place target
    tilt: float | None = None         # rad, measured box up axis from the vertical
    box_pose: np.ndarray | None = None  # (6,) measured final pose: x, y, z (bottom centre, m), roll, pitch, yaw (rad)
    lift: float | None = None         # m, highest rise of the box's bottom above its start
    slip: float | None = None         # m, largest box displacement in the gripper while carried
    collision: str = ""               # the first arm-fixture contact ("<robot part> / <fixture part> at t s")
    tracking_max: np.ndarray | None = None  # (n,) rad per joint: max |q_measured - q_commanded|
    tracking_rms: np.ndarray | None = None  # (n,) rad per joint: RMS of the same
    place_target: np.ndarray | None = field(default=None)  # (3,) m, where the box was to stand (the lab's mark)

    def validate(self) -> "PickPlaceMeasurement":
        super().validate()
        for name in BOOLEANS:
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise MeasurementError(f"measurement field {name!r} must be true or false, got {getattr(self, name)!r}")
            setattr(self, name, bool(getattr(self, name)))
        for name in NUMBERS:
            setattr(self, name, _opt_float(getattr(self, name), name))
        self.box_pose = _opt_vector(self.box_pose, "box_pose", 6)
        self.place_target = _opt_vector(self.place_target, "place_target", 3)
        n = self.plan.q.shape[1] if self.plan.q.ndim == 2 else None
        self.tracking_max = _opt_vector(self.tracking_max, "tracking_max", n)
        self.tracking_rms = _opt_vector(self.tracking_rms, "tracking_rms", n)
        self.collision = str(self.collision or "")
        if self.success and self.raised_flags:
            raise MeasurementError(f"measurement says success with flags raised: {self.raised_flags}")
        return self

    @property
    def ok(self) -> bool:
        """True for a successful trial (placed upright within tolerance, nothing flagged)."""
        return self.success and not self.raised_flags

    def summary_row(self) -> dict[str, str]:
        def num(x):
            return "" if x is None else repr(float(x))

        pose = [None] * 6 if self.box_pose is None else list(self.box_pose)
        return {"success": "1" if self.success else "0", "place_error": num(self.place_error), "tilt": num(self.tilt),
                "box_x": num(pose[0]), "box_y": num(pose[1]), "box_z": num(pose[2]), "box_yaw": num(pose[5])}

    def progress_text(self) -> str:
        err = "not measured" if self.place_error is None else f"{100 * self.place_error:.1f} cm"
        return f"{'success' if self.success else 'failed'}, place error {err}, flags {','.join(self.raised_flags) or '-'}"

    def result_dict(self) -> dict[str, Any]:
        def lst(x):
            return None if x is None else np.asarray(x).tolist()

        r = {k: getattr(self, k) for k in (*BOOLEANS, *NUMBERS, "collision")}
        r.update(box_pose=lst(self.box_pose), tracking_max=lst(self.tracking_max), tracking_rms=lst(self.tracking_rms),
                 place_target=lst(self.place_target))
        return {"result": r}

    @classmethod
    def result_kwargs(cls, d: dict[str, Any]) -> dict[str, Any]:
        r = d.get("result")
        if r is None:
            return {}
        if not isinstance(r, dict):
            raise MeasurementError(f"measurement field 'result' must be a JSON object, got {type(r).__name__}")
        known = (*BOOLEANS, *NUMBERS, "collision", "box_pose", "tracking_max", "tracking_rms", "place_target")
        return {k: r[k] for k in known if k in r}  # a reader accepts fields it does not know (a later writer's)


__all__ = ["PickPlaceMeasurement", "SUMMARY"]
