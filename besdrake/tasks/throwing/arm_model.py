"""Kinematics of a human throwing arm for the synthetic demonstrator.

The model is a trunk (hip pivot, yaw and forward pitch), a right shoulder, a two-link arm
(upper arm, forearm) solved by analytic inverse kinematics with an elbow "swivel" hint, and a
hand frame. Marker plates are rigid triples in a local frame (metres).

Frames: world Z is up. The trunk frame has x forward, y to the subject's left, z up.
The hand frame has x along the forearm towards the fingers, z out of the back of the hand
(dorsal), y = z cross x. Quaternions are (w, x, y, z), scalar first.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from besdrake.mocap.preprocess import rotation_to_quaternion

#: Back plate marker coordinates in the trunk frame, relative to the plate origin (metres).
#: Pairwise distances 58 / 65 / 29 mm (top-right / top-left / right-left), like the real plates.
BACK_PLATE = {
    "Back top": np.array([0.0, 0.0, 0.045]),
    "Back right": np.array([0.002, -0.014, -0.0115]),
    "Back left": np.array([-0.002, 0.0142, -0.0185]),
}
#: Hand plate marker coordinates in the hand frame, relative to the hand centre (metres),
#: on the back of the hand. Pairwise distances 51 / 49 / 33 mm, like the real plates.
HAND_PLATE = {
    "Hand top": np.array([0.030, 0.0, 0.02]),
    "Hand right": np.array([-0.018, -0.0165, 0.02]),
    "Hand left": np.array([-0.0165, 0.0162, 0.02]),
}


def min_jerk(tau: np.ndarray) -> np.ndarray:
    """Minimum-jerk phase 10 t^3 - 15 t^4 + 6 t^5 on [0, 1], clipped outside (bell-shaped speed)."""
    t = np.clip(tau, 0.0, 1.0)
    return t**3 * (10.0 + t * (-15.0 + 6.0 * t))


def bump(tau: np.ndarray) -> np.ndarray:
    """A smooth there-and-back bump 16 t^2 (1 - t)^2 (0 at both ends, 1 in the middle)."""
    t = np.clip(tau, 0.0, 1.0)
    return 16.0 * t**2 * (1.0 - t) ** 2


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(n, 1e-12)


def soft_reach(
    rel: np.ndarray, reach: float, knee: float = 0.9, span: float = 0.07, low_knee: float = 0.45, low_span: float = 0.1
) -> np.ndarray:
    """Scale shoulder-to-wrist vectors smoothly so their length stays between
    ``(low_knee - low_span) * reach`` (the elbow never folds completely) and ``(knee + span) * reach``."""
    r = np.linalg.norm(rel, axis=-1, keepdims=True) / reach
    r_new = np.where(r < knee, r, knee + span * np.tanh((r - knee) / span))
    r_new = np.where(r_new > low_knee, r_new, low_knee - low_span * np.tanh((low_knee - r_new) / low_span))
    return rel * (r_new / np.maximum(r, 1e-12))


def two_link_elbow(shoulder: np.ndarray, wrist: np.ndarray, l1: float, l2: float, hint: np.ndarray) -> np.ndarray:
    """Elbow positions of a two-link arm (vectorised over the leading axis).

    ``hint`` gives the direction the elbow points to (its component perpendicular to the
    shoulder-wrist line is used).
    """
    sw = wrist - shoulder
    d = np.linalg.norm(sw, axis=-1, keepdims=True)
    d = np.clip(d, abs(l1 - l2) + 1e-6, l1 + l2 - 1e-6)
    n = sw / np.maximum(np.linalg.norm(sw, axis=-1, keepdims=True), 1e-12)
    a = (l1**2 - l2**2 + d**2) / (2.0 * d)
    r = np.sqrt(np.maximum(l1**2 - a**2, 0.0))
    perp = _unit(hint - np.sum(hint * n, axis=-1, keepdims=True) * n)
    return shoulder + a * n + r * perp


def hand_frame(elbow: np.ndarray, wrist: np.ndarray, shoulder: np.ndarray, pronation: np.ndarray) -> np.ndarray:
    """Hand rotation matrices ``(n, 3, 3)`` (columns x, y, z) from the arm and a pronation angle."""
    x = _unit(wrist - elbow)
    n_arm = _unit(np.cross(elbow - shoulder, wrist - elbow))
    c, s = np.cos(pronation)[:, None], np.sin(pronation)[:, None]
    z = _unit(c * n_arm + s * np.cross(x, n_arm))
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


def trunk_rotation(yaw: np.ndarray, pitch: np.ndarray, heading: float) -> np.ndarray:
    """Trunk rotation matrices: heading + yaw about world z, then forward pitch about trunk y."""
    return Rotation.from_euler("ZY", np.stack([heading + yaw, pitch], axis=-1)).as_matrix()


def plate_points(origin: np.ndarray, rot: np.ndarray, plate: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """World positions ``(n, 3)`` of each plate marker for poses (origin ``(n,3)``, rot ``(n,3,3)``)."""
    return {name: origin + rot @ local for name, local in plate.items()}


def fit_plate_pose(points: np.ndarray, plate: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares (Kabsch) pose of a rigid plate from observed markers.

    ``points`` is ``(n, k, 3)`` in the order of ``plate``'s keys. Returns the plate origin
    ``(n, 3)`` and quaternions ``(n, 4)`` (w, x, y, z); rows with a missing marker give NaN.
    """
    local = np.stack(list(plate.values()))  # (k, 3)
    lc = local.mean(axis=0)
    pc = points.mean(axis=1)  # (n, 3)
    h = np.einsum("ki,nkj->nij", local - lc, points - pc[:, None, :])
    u, _, vt = np.linalg.svd(np.nan_to_num(h))
    d = np.sign(np.linalg.det(np.einsum("nij,njk->nik", u, vt).transpose(0, 2, 1)))
    fix = np.ones((len(points), 3))
    fix[:, 2] = d
    rot = np.einsum("nji,nj,nkj->nik", vt, fix, u)  # V diag(1,1,d) U^T
    origin = pc - np.einsum("nij,j->ni", rot, lc)
    quat = rotation_to_quaternion(rot)
    bad = np.isnan(points).any(axis=(1, 2))
    origin[bad] = np.nan
    quat[bad] = np.nan
    return origin, quat


def quaternion_to_rotation(q: np.ndarray) -> np.ndarray:
    """Quaternions ``(n,4)`` (w, x, y, z) -> rotation matrices ``(n,3,3)``."""
    return Rotation.from_quat(np.concatenate([q[:, 1:], q[:, :1]], axis=1)).as_matrix()


def ballistic_speed(direction: np.ndarray, height: float, distance: float, g: float = 9.81) -> float:
    """Launch speed along unit ``direction`` (world, z up) that lands ``distance`` metres away
    horizontally after falling from ``height`` metres above the ground."""
    horiz = float(np.hypot(direction[0], direction[1]))
    vert = float(direction[2])
    if horiz < 1e-3:
        raise ValueError("launch direction is vertical")

    def range_at(v: float) -> float:
        vz, vh = v * vert, v * horiz
        t_land = (vz + np.sqrt(vz**2 + 2.0 * g * max(height, 1e-3))) / g
        return vh * t_land

    lo, hi = 0.01, 50.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if range_at(mid) < distance else (lo, mid)
    return 0.5 * (lo + hi)
