"""What a pick-and-place rollout measured, whether it succeeded, and its reward.

Failure flags: ``not_lifted`` (the box never rose clear of the shelf), ``slipped`` (the fingers closed on the box
but it was not lifted with them, or moved in the gripper before the release: a grasp too weak for its friction),
``dropped`` (it ended below the table top), ``not_upright``, ``missed_place``, ``arm_fixture_collision``,
``joint_limit_exceeded``, ``sim_failed``.

Success (issue 24): the box was lifted clear of the shelf and held (no slip) until the gripper opened, stands
upright on the table within ``place_tolerance`` of the target place, no part of the robot touched a fixture,
and the joint limits were kept. The reward is continuous for CMA-ES: minus a cost in metres (the final distance
of the box from its target place) plus penalties for each failure (:data:`PENALTIES`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: Names of the outcome's flags (True = that failure happened).
FLAG_NAMES = ("sim_failed", "not_lifted", "slipped", "dropped", "not_upright", "missed_place",
              "arm_fixture_collision", "joint_limit_exceeded")

#: Cost (m) added per failure; the final place distance (m, at most ``MAX_DISTANCE``) is added to them.
PENALTIES = {"sim_failed": 2.0, "not_lifted": 0.5, "slipped": 0.25, "dropped": 0.25, "not_upright": 0.25,
             "arm_fixture_collision": 0.5, "joint_limit_exceeded": 1.0}
MAX_DISTANCE = 2.0


@dataclass(frozen=True)
class PickPlaceCriteria:
    """Thresholds of success: ``lift_clearance`` (m) the box's bottom must rise above its start; ``slip_tolerance``
    (m) the box may move in the gripper between the lift and the release; ``place_tolerance`` (m, horizontal)
    from the target place; ``upright_tolerance`` (rad) of tilt; ``rest_tolerance`` (m) between the box's bottom and
    the table top at the end; ``tail`` (s) simulated after the plan's end (the box settles)."""

    lift_clearance: float = 0.02
    slip_tolerance: float = 0.02
    place_tolerance: float = 0.03
    upright_tolerance: float = float(np.radians(10.0))
    rest_tolerance: float = 0.01
    tail: float = 0.5


@dataclass
class PickPlaceOutcome:
    """A pick-and-place rollout's result (SI units; positions in the world frame)."""

    success: bool = False
    reward: float = float("-inf")
    grasped: bool = False                      # the closed fingers stopped on something (the box) 0.1 s after closing
    lifted: bool = False
    held: bool = False
    upright: bool = False
    on_table: bool = False
    limits_kept: bool = True
    arm_fixture_collision: bool = False
    collision: str = ""                         # "<robot geometry> / <fixture geometry> at t s", the first seen
    place_error: float = float("nan")           # m, horizontal distance of the box's bottom centre from the target
    tilt: float = float("nan")                  # rad, angle of the box's up axis from the vertical
    box_position: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))   # final bottom centre (m)
    box_quaternion: np.ndarray = field(default_factory=lambda: np.full(4, np.nan))  # final orientation (w, x, y, z)
    max_slip: float = 0.0                       # m, largest box displacement in the gripper while held
    sim_time: float = 0.0
    flags: dict[str, bool] = field(default_factory=lambda: {k: False for k in FLAG_NAMES})
    message: str = ""
    t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    q_arm: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  # arm joints as the encoders read them (rad)
    q_commanded: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  # the plan's arm joints at ``t`` (rad)
    box_path: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no time series)."""
        return {
            "success": self.success, "reward": self.reward, "grasped": self.grasped, "lifted": self.lifted, "held": self.held,
            "upright": self.upright, "on_table": self.on_table, "limits_kept": self.limits_kept,
            "arm_fixture_collision": self.arm_fixture_collision, "collision": self.collision,
            "place_error_m": self.place_error, "tilt_rad": self.tilt, "box_position": self.box_position.tolist(),
            "box_quaternion": self.box_quaternion.tolist(), "max_slip_m": self.max_slip, "sim_time_s": self.sim_time,
            "flags": dict(self.flags), "message": self.message,
        }


def failed_outcome(message: str) -> PickPlaceOutcome:
    """The outcome of a rollout that could not run: flagged ``sim_failed``, the worst reward."""
    out = PickPlaceOutcome(message=message)
    out.flags["sim_failed"] = True
    out.reward = -(MAX_DISTANCE + PENALTIES["sim_failed"])
    return out


def score(out: PickPlaceOutcome, target: np.ndarray, criteria: PickPlaceCriteria) -> None:
    """Set ``out``'s success, failure flags and reward from its measurements (``target``: the place, m)."""
    f = out.flags
    f["not_lifted"] = not out.lifted
    f["slipped"] = out.grasped and not (out.lifted and out.held)
    f["not_upright"] = not out.upright
    f["missed_place"] = not (out.on_table and out.place_error <= criteria.place_tolerance)
    f["arm_fixture_collision"] = out.arm_fixture_collision
    f["joint_limit_exceeded"] = not out.limits_kept
    out.success = not any(f.values())
    if f["sim_failed"] or not np.all(np.isfinite(out.box_position)):
        distance = MAX_DISTANCE
    else:
        distance = min(float(np.linalg.norm(out.box_position - target)), MAX_DISTANCE)
    out.reward = -(distance + sum(p for k, p in PENALTIES.items() if f.get(k)))
    if not out.message:
        failed = [k for k, v in f.items() if v]
        out.message = "success" if out.success else "failed: " + ", ".join(failed)
