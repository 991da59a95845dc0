"""The pick-and-place task frame: tied to the shelf and the table, not to where the person stood.

Definition (one frame per grasp demonstration, from that demonstration's own box places):

* origin: the box's rest position on the shelf before the grasp (the midpoint of the markers
  ``Box back`` and ``Box left``);
* z: the lab's vertical, up (the capture system's Z axis: Qualisys calibrates Z up);
* x: horizontal, from the box's place on the shelf towards its place on the table;
* y = z x x (right-handed).

So the table place is ``(d, 0, h)``: ``d`` the horizontal shelf-table distance and ``h`` the
height of the table place relative to the shelf place (negative: the table is lower). A hand
path in this frame does not change when the person, the shelf and the table all stand elsewhere
in the capture volume or face another way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The lab's up direction in capture coordinates (Qualisys: +Z).
LAB_UP = np.array([0.0, 0.0, 1.0])
#: Shelf and table places closer than this horizontally define no x axis (metres).
MIN_HORIZONTAL_DISTANCE_M = 0.05


class TaskFrameError(ValueError):
    """Box places that define no task frame (the same place, or non-finite)."""


@dataclass
class TaskFrame:
    """A rigid frame in capture (world) coordinates.

    Attributes:
        origin: ``(3,)`` metres, world.
        rotation: ``(3, 3)``, columns are the task x, y, z axes in world coordinates.
    """

    origin: np.ndarray
    rotation: np.ndarray

    def points(self, world: np.ndarray) -> np.ndarray:
        """World points ``(..., 3)`` in task coordinates."""
        return (np.asarray(world, dtype=float) - self.origin) @ self.rotation

    def rotations(self, world: np.ndarray) -> np.ndarray:
        """World orientations ``(n, 3, 3)`` (columns: body axes) in task coordinates."""
        return np.einsum("ji,njk->nik", self.rotation, np.asarray(world, dtype=float))

    def directions(self, world: np.ndarray) -> np.ndarray:
        """World direction vectors ``(..., 3)`` in task coordinates (no translation)."""
        return np.asarray(world, dtype=float) @ self.rotation


def task_frame(shelf_place: np.ndarray, table_place: np.ndarray, up: np.ndarray = LAB_UP) -> TaskFrame:
    """The task frame from the box's places on the shelf and on the table (world, metres)."""
    shelf, table = np.asarray(shelf_place, dtype=float), np.asarray(table_place, dtype=float)
    if not (np.isfinite(shelf).all() and np.isfinite(table).all()):
        raise TaskFrameError("the box places on the shelf and the table must be finite")
    z = np.asarray(up, dtype=float) / np.linalg.norm(up)
    d = table - shelf
    x = d - np.dot(d, z) * z
    dist = float(np.linalg.norm(x))
    if dist < MIN_HORIZONTAL_DISTANCE_M:
        raise TaskFrameError(
            f"the box's table place is only {dist * 100:.1f} cm from its shelf place horizontally "
            f"(at least {MIN_HORIZONTAL_DISTANCE_M * 100:.0f} cm are needed for the task frame's x axis)"
        )
    x /= dist
    return TaskFrame(origin=shelf.copy(), rotation=np.stack([x, np.cross(z, x), z], axis=1))


def horizontal_yaw(direction_task: np.ndarray) -> np.ndarray:
    """Yaw (rad, about task z, from task x) of direction vectors ``(..., 3)`` in task coordinates."""
    d = np.asarray(direction_task, dtype=float)
    return np.arctan2(d[..., 1], d[..., 0])
