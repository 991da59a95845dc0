"""Facts about the COMPI arm (DFKI) with its throwing scoop: joint names, limits, model files.

Kinematics follow DFKI's published URDF (see ``models/compi/compi.urdf``). Position limits
for joints 1-5 and the 3.14 rad/s motor speed limit are the published values used for COMPI;
the others are our documented choices:

* joint6 position limit: +-pi (not published; the wrist roll has no hard stop in the model).
* acceleration limit: 20 rad/s^2 on every joint. Not published; chosen so that a full-speed
  joint (3.14 rad/s) can stop within ~0.16 s, which matches the short, snappy throws of the
  BesMan experiments while staying well inside what small servo drives deliver.

Other stages (inverse kinematics, the lab's safety gate) import these constants; the
simulation uses them to validate motion plans.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: The six revolute joints, base to wrist.
JOINT_NAMES: tuple[str, ...] = ("joint1", "joint2", "joint3", "joint4", "joint5", "joint6")

#: Position limits in rad, one row [lower, upper] per joint (joint6: our choice, +-pi).
POSITION_LIMITS: np.ndarray = np.array(
    [
        [-np.pi, np.pi],
        [-1.8, 2.09],
        [-2.3, 2.3],
        [-np.pi, np.pi],
        [-2.0, 2.0],
        [-np.pi, np.pi],
    ]
)
POSITION_LIMITS.setflags(write=False)

#: Motor speed limit in rad/s (published: 3.14 rad/s for every joint).
VELOCITY_LIMITS: np.ndarray = np.full(6, 3.14)
VELOCITY_LIMITS.setflags(write=False)

#: Acceleration limit in rad/s^2 (our documented choice, see module docstring).
ACCELERATION_LIMITS: np.ndarray = np.full(6, 20.0)
ACCELERATION_LIMITS.setflags(write=False)

#: Repository folder that holds the model files and ``package.xml`` (package ``besdrake_models``).
MODELS_DIR: Path = Path(__file__).resolve().parent / "models"
PACKAGE_NAME = "besdrake_models"

#: Model instance name of the arm in the plant.
MODEL_INSTANCE = "compi"
#: Frame of the arm's base link (welded to the world through a movable base frame).
BASE_LINK = "linkmount"
#: Tool centre point: at the wrist flange, 0.05 m beyond joint6 along the last link.
TCP_FRAME = "tcp"
#: Body of the scoop (welded to the tcp); its frame's +z is the scoop's opening direction.
SCOOP_BODY = "scoop"
#: Body of the ball in the plant.
BALL_BODY = "ball"

#: Height of the tcp above the base at q = 0 (arm pointing straight up), in m.
TCP_HEIGHT_AT_ZERO = 0.158 + 0.28 + 0.34 + 0.346 + 0.05


def compi_model_path() -> Path:
    """Path of COMPI's URDF (arm + scoop collision geometry)."""
    path = MODELS_DIR / "compi" / "compi.urdf"
    if not path.is_file():
        raise FileNotFoundError(f"COMPI model file missing: {path}")
    return path


def package_xml_path() -> Path:
    """Path of ``models/package.xml`` that makes ``package://besdrake_models/...`` resolve."""
    path = MODELS_DIR / "package.xml"
    if not path.is_file():
        raise FileNotFoundError(f"model package file missing: {path}")
    return path


def add_package(package_map) -> None:
    """Add the ``besdrake_models`` package to a Drake ``PackageMap`` (idempotent)."""
    if not package_map.Contains(PACKAGE_NAME):
        package_map.AddPackageXml(str(package_xml_path()))


def package_map():
    """A fresh Drake ``PackageMap`` that knows ``besdrake_models``."""
    from pydrake.multibody.parsing import PackageMap

    pm = PackageMap()
    add_package(pm)
    return pm


def in_limits(q: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """Boolean mask: which entries of ``q`` (..., 6) lie within the position limits (minus margin)."""
    q = np.asarray(q, dtype=float)
    return (q >= POSITION_LIMITS[:, 0] + margin) & (q <= POSITION_LIMITS[:, 1] - margin)


# Scoop geometry (must match models/compi/compi.urdf; see the comment there), in the scoop frame
# whose +z is the opening direction. A square funnel with 45-degree walls.
SCOOP_BOTTOM_HALF_WIDTH = 0.015  # m, half-width of the funnel at z = 0
SCOOP_WALL_ANGLE = np.pi / 4  # rad, wall inclination from the scoop's base plane
SCOOP_LIP_HEIGHT = 0.045  # m, height of the walls' top edge above z = 0
SCOOP_TOP_HALF_WIDTH = SCOOP_BOTTOM_HALF_WIDTH + SCOOP_LIP_HEIGHT / np.tan(SCOOP_WALL_ANGLE)
SCOOP_FLOOR_Z = -0.0045  # m, top of the safety floor plate


def ball_rest_height(radius: float) -> float:
    """Height (m, scoop frame z) of the centre of a ball of ``radius`` resting on the funnel walls."""
    a = SCOOP_BOTTOM_HALF_WIDTH
    s = np.sin(SCOOP_WALL_ANGLE)
    c = np.cos(SCOOP_WALL_ANGLE)
    return max((radius - a * s) / c, SCOOP_FLOOR_Z + radius)


def scoop_surfaces() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The scoop's contact surfaces as rectangles in the scoop frame: origins (5, 3) (centre of the bottom
    edge of each wall, centre of the floor plate), unit axes ``u`` (5, 3) (up the wall / along x) and ``w``
    (5, 3) (along the wall / along y), and half-extents (5, 2) along them (``u`` measured from 0 for walls).
    The four 45-degree walls' inner faces and the floor plate's top face, as in ``compi.urdf``."""
    a, h, al = SCOOP_BOTTOM_HALF_WIDTH, SCOOP_LIP_HEIGHT, SCOOP_WALL_ANGLE
    length = h / np.sin(al)
    half_w = SCOOP_TOP_HALF_WIDTH + 0.005
    c, s = np.cos(al), np.sin(al)
    origins = np.array([[a, 0, 0], [-a, 0, 0], [0, a, 0], [0, -a, 0], [0, 0, SCOOP_FLOOR_Z]], dtype=float)
    u = np.array([[c, 0, s], [-c, 0, s], [0, c, s], [0, -c, s], [1, 0, 0]], dtype=float)
    w = np.array([[0, 1, 0], [0, 1, 0], [1, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=float)
    floor_half = a + 0.005
    ext = np.array([[length, half_w]] * 4 + [[floor_half, floor_half]], dtype=float)
    return origins, u, w, ext


_SURFACES = None


def distance_to_scoop(p_S: np.ndarray) -> np.ndarray | float:
    """Distance (m) from point(s) in the scoop frame, shape (3,) or (K, 3), to the nearest scoop surface
    (a ball of radius r touches the scoop when this is < r)."""
    global _SURFACES
    if _SURFACES is None:
        origins, u, w, ext = scoop_surfaces()
        lo_u = np.where(np.arange(len(origins)) < 4, 0.0, -ext[:, 0])
        _SURFACES = (origins, u, w, ext, lo_u)
    origins, u, w, ext, lo_u = _SURFACES
    pts = np.asarray(p_S, dtype=float)
    single = pts.ndim == 1
    pts = np.atleast_2d(pts)
    rel = pts[:, None, :] - origins[None, :, :]  # (K, 5, 3)
    cu = np.clip(np.einsum("kij,ij->ki", rel, u), lo_u, ext[:, 0])
    cw = np.clip(np.einsum("kij,ij->ki", rel, w), -ext[:, 1], ext[:, 1])
    closest = origins[None] + cu[..., None] * u[None] + cw[..., None] * w[None]
    d = np.min(np.linalg.norm(pts[:, None, :] - closest, axis=2), axis=1)
    return float(d[0]) if single else d
