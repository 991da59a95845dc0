"""The throwing scoop's geometry: a square funnel with inclined walls over a safety floor plate.

The numbers come from the robot file's ``end_effector.params`` (``besdrake/models/compi/robot.yaml``), which
``generate_urdf.py`` also reads to write the collision geometry, so the simulation and the model agree.
Everything is in the scoop frame, whose +z is the opening direction.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from besdrake.robot import Robot, RobotError

_PARAMS = ("bottom_half_width", "wall_angle", "lip_height", "floor_z")


@dataclass(frozen=True)
class Scoop:
    """Funnel half-width at z = 0 (m), wall inclination from the base plane (rad), lip height (m) and the
    height of the floor plate's top (m)."""

    bottom_half_width: float = 0.015
    wall_angle: float = np.pi / 4
    lip_height: float = 0.045
    floor_z: float = -0.0045

    @classmethod
    def of(cls, robot: Robot) -> "Scoop":
        """The scoop of ``robot`` (a fixed end effector whose params give the geometry)."""
        params = robot.end_effector.params
        missing = [k for k in _PARAMS if k not in params]
        if missing:
            raise RobotError(f"{robot.path}: end_effector.params: a scoop needs {missing}")
        bad = [k for k in _PARAMS if isinstance(params[k], bool) or not isinstance(params[k], (int, float)) or not np.isfinite(params[k])]
        if bad:
            raise RobotError(f"{robot.path}: end_effector.params.{bad[0]}: must be a finite number, got {params[bad[0]]!r}")
        return cls(**{k: float(params[k]) for k in _PARAMS})

    @property
    def top_half_width(self) -> float:
        """Half-width (m) of the funnel at the lip."""
        return self.bottom_half_width + self.lip_height / np.tan(self.wall_angle)

    def rest_height(self, radius: float) -> float:
        """Height (m, z) of the centre of a ball of ``radius`` resting on the funnel walls."""
        a, s, c = self.bottom_half_width, np.sin(self.wall_angle), np.cos(self.wall_angle)
        return max((radius - a * s) / c, self.floor_z + radius)

    def surfaces(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The contact surfaces as rectangles: origins (5, 3) (centre of the bottom edge of each wall, centre of
        the floor plate), unit axes ``u`` (up the wall / along x) and ``w`` (along the wall / along y), and
        half-extents (5, 2) along them (``u`` measured from 0 for walls): the four walls' inner faces and the
        floor plate's top face."""
        a, h, al = self.bottom_half_width, self.lip_height, self.wall_angle
        length = h / np.sin(al)
        half_w = self.top_half_width + 0.005
        c, s = np.cos(al), np.sin(al)
        origins = np.array([[a, 0, 0], [-a, 0, 0], [0, a, 0], [0, -a, 0], [0, 0, self.floor_z]], dtype=float)
        u = np.array([[c, 0, s], [-c, 0, s], [0, c, s], [0, -c, s], [1, 0, 0]], dtype=float)
        w = np.array([[0, 1, 0], [0, 1, 0], [1, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=float)
        floor_half = a + 0.005
        ext = np.array([[length, half_w]] * 4 + [[floor_half, floor_half]], dtype=float)
        return origins, u, w, ext

    @cached_property
    def _rectangles(self) -> tuple[np.ndarray, ...]:
        origins, u, w, ext = self.surfaces()
        return origins, u, w, ext, np.where(np.arange(len(origins)) < 4, 0.0, -ext[:, 0])

    def distance(self, p_S: np.ndarray) -> np.ndarray | float:
        """Distance (m) from point(s) (3,) or (K, 3) to the nearest scoop surface (a ball of radius r touches
        the scoop when this is < r)."""
        pts = np.asarray(p_S, dtype=float)
        single = pts.ndim == 1
        if single and pts.shape == (3,) and np.isfinite(pts).all():
            return self.distance_to_point(float(pts[0]), float(pts[1]), float(pts[2]))
        origins, u, w, ext, lo_u = self._rectangles
        pts = np.atleast_2d(pts)
        rel = pts[:, None, :] - origins[None, :, :]  # (K, 5, 3)
        cu = np.clip(np.einsum("kij,ij->ki", rel, u), lo_u, ext[:, 0])
        cw = np.clip(np.einsum("kij,ij->ki", rel, w), -ext[:, 1], ext[:, 1])
        closest = origins[None] + cu[..., None] * u[None] + cw[..., None] * w[None]
        d = np.min(np.linalg.norm(pts[:, None, :] - closest, axis=2), axis=1)
        return float(d[0]) if single else d

    @cached_property
    def _rectangle_floats(self) -> tuple[tuple[float, ...], ...]:
        origins, u, w, ext, lo_u = self._rectangles
        return tuple(tuple(float(v) for v in (*origins[k], *u[k], *w[k], lo_u[k], ext[k, 0], ext[k, 1])) for k in range(len(origins)))

    def distance_to_point(self, x: float, y: float, z: float) -> float:
        """:meth:`distance` of the finite point (x, y, z) in plain float arithmetic (4 us against 120 us for the array
        path: the rollout's per-chunk check; the same formula)."""
        best = np.inf
        for ox, oy, oz, ux, uy, uz, wx, wy, wz, lo, hi_u, hi_w in self._rectangle_floats:
            rx, ry, rz = x - ox, y - oy, z - oz
            cu = rx * ux + ry * uy + rz * uz
            cu = lo if cu < lo else (hi_u if cu > hi_u else cu)  # clipped to the rectangle (no builtin calls: hot path)
            cw = rx * wx + ry * wy + rz * wz
            cw = -hi_w if cw < -hi_w else (hi_w if cw > hi_w else cw)
            dx, dy, dz = rx - cu * ux - cw * wx, ry - cu * uy - cw * wy, rz - cu * uz - cw * wz
            d2 = dx * dx + dy * dy + dz * dz
            best = d2 if d2 < best else best
        return float(np.sqrt(best))

