"""The grasp skill: a grasp demonstration imitated as two chained Cartesian DMPs plus a gripper timing.

What is imitated (all in the task frame, :mod:`~besdrake.tasks.pick_and_place.task_frame`):

* **the grasp point's pose**, not the hand plate's: the hand plate sits on the back of the hand, some
  20 cm from the box it holds. The box's midpoint in the hand plate frame is nearly constant while it
  is carried (measured on the 15 shared demonstrations: 1-12 mm standard deviation per axis), so its
  median over the carry (lift to place) is the *grasp offset*, and the grasp point's path is
  ``hand_position + R_hand @ grasp_offset`` with the hand plate's orientation. During the carry it
  follows the box; the robot's tool frame (between the gripper's pads) is driven along it.
* **two segments**, split at the demonstration's ``border_index``: the approach (to the box on the
  shelf) and the transport (to the table). Each is a :class:`~besdrake.imitation.cartesian.CartesianDMP`.
  The approach ends with the demonstrated velocity (its goal velocity); the transport is fitted
  starting with that velocity and, when rolled out, starts where the approach ended, with the
  velocity it ended with (chained). The orientation DMPs end and start at rest (Ude's formulation
  has no goal angular velocity).
* **the gripper timing** (s from the approach's start): the gripper closes over the approach's last
  ``close_duration`` s, so that it is closed when the tool arrives on the box, and opens at the
  demonstrated open time. The demonstrated close time (kept as ``demo_close_time``) lies 0-0.9 s
  before the approach's end in the shared recordings, or just after it: a hand closes while it
  settles on the box and lifts as it closes; a robot gripper closed 0.7 s early (measured on
  subject1_run5) closes 11 mm short of the box, one closed late is still opening while the transport
  lifts. Refinement may move the close time (:mod:`~besdrake.tasks.pick_and_place.parameters`).

Spatial generalisation (the DMPs' goals are meta-parameters, :meth:`GraspSkill.adapted`): the
approach's goal is the scene's box place on the shelf (the task frame's origin) plus ``grasp_offset``
(the tool relative to the box, default 0: the tool frame at the box's midpoint); the transport's goal
is the scene's table place plus the demonstrated end of the transport relative to the demonstrated
table place (the hand's release and retreat). With the scene's places equal to the demonstrated ones
only the approach's goal moves: by the person's grasp imprecision, 1-4 cm in the shared recordings.

The robot side (hand-to-tool rotation, IK, temporal scaling, the plan) is in
:mod:`~besdrake.tasks.pick_and_place.grasp_plan`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from besdrake.imitation import quaternion as quat
from besdrake.imitation._validation import DMPParameterError
from besdrake.imitation.cartesian import CartesianDMP, CartesianTrajectory

#: Weights per dimension of both segments' DMPs.
GRASP_WEIGHTS_PER_DIM = 20
#: Fewest samples a segment of a demonstration must have.
MIN_SEGMENT_SAMPLES = 10
#: Time (s) a robot gripper takes from open to closed (and back) in the default command.
DEFAULT_CLOSE_DURATION = 0.2


class GraspImitationError(ValueError):
    """A grasp demonstration that cannot be imitated (NaN, too short, inconsistent events)."""


def check_demonstration(demo) -> None:
    """Raise :class:`GraspImitationError` naming the first problem of ``demo`` (a GraspDemonstration)."""
    n = len(demo.t)
    for name in ("t", "hand_position", "hand_orientation", "box_position"):
        arr = np.asarray(getattr(demo, name), dtype=float)
        if len(arr) != n:
            raise GraspImitationError(f"{demo.source}: {name} has {len(arr)} samples, t has {n}")
        if not np.isfinite(arr).all():
            raise GraspImitationError(f"{demo.source}: {name} contains NaN or infinite values")
    if n < 2 or np.any(np.diff(demo.t) <= 0):
        raise GraspImitationError(f"{demo.source}: times must increase strictly (got {n} samples)")
    b = int(demo.border_index)
    if b < MIN_SEGMENT_SAMPLES - 1 or n - b < MIN_SEGMENT_SAMPLES:
        raise GraspImitationError(f"{demo.source}: approach ({b + 1} samples) and transport ({n - b}) need at least "
                                  f"{MIN_SEGMENT_SAMPLES} samples each")
    events = [demo.close_time, demo.lift_time, demo.place_time, demo.open_time]
    if not np.isfinite(events).all() or not demo.close_time <= demo.lift_time < demo.place_time <= demo.open_time:
        raise GraspImitationError(f"{demo.source}: grasp events out of order (close, lift, place, open = {events})")


def rotation_matrices(q: np.ndarray) -> np.ndarray:
    """Quaternions (n, 4; w first) -> rotation matrices (n, 3, 3)."""
    w, x, y, z = np.asarray(q, dtype=float).T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=1)


def grasp_point_path(demo) -> tuple[np.ndarray, np.ndarray]:
    """The grasp point's path (n, 3) in the task frame and the grasp offset (3,) in the hand plate frame
    (see the module docstring)."""
    R = rotation_matrices(quat.make_continuous(demo.hand_orientation))
    carry = (demo.t >= demo.lift_time) & (demo.t <= demo.place_time)
    if carry.sum() < 2:
        raise GraspImitationError(f"{demo.source}: fewer than 2 samples while the box is carried")
    box_in_hand = np.einsum("nji,nj->ni", R[carry], demo.box_position[carry] - demo.hand_position[carry])
    offset = np.median(box_in_hand, axis=0)
    return demo.hand_position + R @ offset, offset


@dataclass
class GraspSkill:
    """Approach and transport DMPs of the grasp point's pose in the task frame, and the gripper timing
    (s from the approach's start, DMP time). ``shelf_place`` / ``table_place`` (3,) m: the box places the
    DMPs' goals refer to (the demonstrated ones until :meth:`adapted`); ``release_offset`` (3,) m: the
    transport's end relative to ``table_place``; ``grasp_offset_hand`` (3,) m: the grasp point in the
    hand plate frame, and ``demo_close_time`` (s): the demonstrated close time (information)."""

    approach: CartesianDMP
    transport: CartesianDMP
    close_time: float
    open_time: float
    shelf_place: np.ndarray
    table_place: np.ndarray
    release_offset: np.ndarray
    grasp_offset_hand: np.ndarray
    demo_close_time: float = float("nan")
    source: str = ""
    closing_axis_hand: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))

    @property
    def duration(self) -> float:
        """Execution time of the approach plus the transport (s)."""
        return self.approach.execution_time + self.transport.execution_time

    @classmethod
    def from_demonstration(cls, demo, n_weights_per_dim: int = GRASP_WEIGHTS_PER_DIM,
                           close_duration: float = DEFAULT_CLOSE_DURATION) -> "GraspSkill":
        """Fit both DMPs to ``demo`` (a GraspDemonstration; :class:`GraspImitationError` if unusable)."""
        check_demonstration(demo)
        path, offset = grasp_point_path(demo)
        q = quat.make_continuous(demo.hand_orientation)
        poses = np.hstack([path, q])
        b = int(demo.border_index)
        try:
            approach = CartesianDMP(n_weights_per_dim).fit(demo.t[: b + 1], poses[: b + 1])
            transport = CartesianDMP(n_weights_per_dim).fit(demo.t[b:], poses[b:],
                                                            start_velocity=approach.goal_velocity)
        except DMPParameterError as err:
            raise GraspImitationError(f"{demo.source}: cannot fit the DMPs: {err}") from err
        tau_a = approach.execution_time
        return cls(approach, transport,
                   close_time=float(tau_a - close_duration), demo_close_time=float(demo.close_time),
                   open_time=float(demo.open_time),
                   shelf_place=np.asarray(demo.shelf_box_position, dtype=float).copy(),
                   table_place=np.asarray(demo.table_box_position, dtype=float).copy(),
                   release_offset=path[-1] - demo.table_box_position,
                   grasp_offset_hand=offset, source=str(demo.source),
                   closing_axis_hand=np.asarray(getattr(demo, "closing_axis_hand", np.full(3, np.nan)), dtype=float))

    def adapted(self, table_place: np.ndarray | None = None, grasp_offset: np.ndarray | None = None,
                start_position: np.ndarray | None = None) -> "GraspSkill":
        """A copy whose goals are the scene's: the approach ends at the box on the shelf (task origin)
        plus ``grasp_offset`` (default 0), the transport at ``table_place`` (default: the demonstrated
        one) plus the demonstrated release offset; ``start_position``: where the approach starts."""
        new = self.copy()
        table = self.table_place if table_place is None else np.asarray(table_place, dtype=float)
        grasp = np.zeros(3) if grasp_offset is None else np.asarray(grasp_offset, dtype=float)
        new.approach.position.goal = grasp
        new.transport.position.goal = table + self.release_offset
        new.shelf_place, new.table_place = np.zeros(3), table.copy()
        if start_position is not None:
            new.approach.position.start = np.asarray(start_position, dtype=float)
        return new

    def reaching_from(self, start_position: np.ndarray, dt: float = 0.01) -> "GraspSkill":
        """A copy whose approach starts at rest at ``start_position`` (task frame, m) and ends as demonstrated.

        A robot starts its approach from its own home pose, often much nearer the box than a person's hand
        hanging at the hip. Moving a DMP's start by a metre keeps the demonstration's deviation from a straight
        line (for a reach from the hip: a rise of half a metre) and sends the tool over the shelf, out of reach.
        Instead, the imitated approach is cropped where it first comes as near its goal as ``start_position``
        is (the reach from the resting hand is dropped; the gripper times move with it), and the rest of the
        path is warped onto the new start: shifted by the start's offset times ``(d / d0)**2``, ``d`` the
        remaining distance to the goal (``d0`` at the start), so that the last stretch towards the box, where
        the demonstration avoids the shelf, keeps its shape. The warped path is fitted again."""
        a = self.approach.open_loop(dt)
        goal = self.approach.position.goal
        distance = np.linalg.norm(a.pose[:, :3] - goal, axis=1)
        radius = float(np.linalg.norm(np.asarray(start_position, dtype=float) - goal))
        inside = np.flatnonzero(distance <= radius)
        k = min(int(inside[0]) if inside.size else 0, max(0, len(a.t) - MIN_SEGMENT_SAMPLES))
        pose = a.pose[k:].copy()
        weight = np.clip(distance[k:] / max(distance[k], 1e-9), 0.0, 1.0) ** 2
        pose[:, :3] += np.outer(weight, np.asarray(start_position, dtype=float) - pose[0, :3])
        new = self.copy()
        new.approach = CartesianDMP(self.approach.position.n_weights_per_dim).fit(a.t[k:], pose)
        new.approach.position.goal = goal  # exactly (the rollout ends within a millimetre of it)
        new.approach.orientation.goal = self.approach.orientation.goal
        new.approach.position.goal_velocity = self.approach.position.goal_velocity
        shift = float(a.t[k])
        new.close_time, new.open_time = self.close_time - shift, self.open_time - shift
        new.demo_close_time = self.demo_close_time - shift
        return new

    def rollout(self, dt: float = 0.01) -> CartesianTrajectory:
        """Both segments rolled out every ``dt`` s; the transport starts where and as fast as the approach ended."""
        a = self.approach.open_loop(dt)
        transport = self.transport.copy()
        transport.position.start = a.pose[-1, :3]
        transport.position.start_velocity = a.velocity[-1, :3]
        transport.orientation.start = a.pose[-1, 3:]
        b = transport.open_loop(dt)
        return CartesianTrajectory(np.concatenate([a.t, a.t[-1] + b.t[1:]]), np.vstack([a.pose, b.pose[1:]]),
                                   np.vstack([a.velocity, b.velocity[1:]]))

    def copy(self) -> "GraspSkill":
        return GraspSkill.from_dict(self.to_dict())

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (SI units)."""
        return {"type": "GraspSkill", "approach": self.approach.to_dict(), "transport": self.transport.to_dict(),
                "close_time": self.close_time, "open_time": self.open_time,
                "shelf_place": self.shelf_place.tolist(), "table_place": self.table_place.tolist(),
                "release_offset": self.release_offset.tolist(), "grasp_offset_hand": self.grasp_offset_hand.tolist(),
                "demo_close_time": self.demo_close_time, "source": self.source,
                "closing_axis_hand": [float(v) for v in self.closing_axis_hand]}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "GraspSkill":
        try:
            return cls(CartesianDMP.from_dict(d["approach"]), CartesianDMP.from_dict(d["transport"]),
                       float(d["close_time"]), float(d["open_time"]),
                       *(np.asarray(d[k], dtype=float) for k in ("shelf_place", "table_place", "release_offset",
                                                                 "grasp_offset_hand")),
                       demo_close_time=float(d.get("demo_close_time", "nan")), source=str(d.get("source", "")),
                       closing_axis_hand=np.asarray(d.get("closing_axis_hand", [np.nan] * 3), dtype=float))
        except (KeyError, TypeError) as err:
            raise GraspImitationError(f"not a grasp skill description: {err}") from err
