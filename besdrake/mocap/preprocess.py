"""Preprocessing of a motion-capture recording for segmentation and classification.

* short gaps (missing samples) are interpolated per marker (:func:`besdrake.mocap.gaps.fill_gaps`) and
  flagged; longer gaps stay NaN;
* the demonstrator's *back frame* is built from the three back markers
  (origin: their centroid; y: from ``Back right`` to ``Back left``; z: from the right/left
  midpoint towards ``Back top``, made orthogonal to y; x = y cross z);
* the hand position (centroid of the hand markers) and orientation (unit quaternion
  ``(w, x, y, z)``, sign-continuous) are computed, in the world and in the back frame;
* velocities come from a Savitzky-Golay derivative (SI units: m/s).

Paper section 2.1 (preprocessing) of the BesMan learning platform.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.signal import savgol_filter

from besdrake.mocap.gaps import fill_gaps, reject_outliers
from besdrake.mocap.recording import MocapRecording

BACK_MARKERS = ("Back top", "Back right", "Back left")
HAND_MARKERS = ("Hand top", "Hand right", "Hand left")

#: Gaps up to this length (seconds) are interpolated; longer gaps stay NaN.
DEFAULT_MAX_GAP_S = 0.25
#: Savitzky-Golay window (seconds) for velocities.
DEFAULT_VELOCITY_WINDOW_S = 0.15


class PreprocessError(ValueError):
    """A recording that cannot be preprocessed (missing marker, too short, unusable gaps)."""


@dataclass
class Preprocessed:
    """Preprocessed trajectories of one recording (SI units).

    Attributes:
        frames: ``(n,)`` the file's frame numbers.
        time: ``(n,)`` seconds.
        frequency: Hz.
        marker_names: names of ``positions_back`` columns.
        positions: ``(n, m, 3)`` world positions after gap filling (NaN in long gaps).
        positions_back: ``(n, m, 3)`` positions in the back frame.
        back_origin: ``(n, 3)``; back_rotation: ``(n, 3, 3)`` columns are the back axes in the world.
        hand_position: ``(n, 3)`` world; hand_position_back: ``(n, 3)`` back frame.
        hand_orientation_back: ``(n, 4)`` unit quaternion ``(w, x, y, z)`` of the hand in the back frame.
        hand_velocity: ``(n, 3)`` world m/s; hand_velocity_back: ``(n, 3)`` back frame m/s
            (derivative of the back-frame position).
        interpolated: ``(n, m)`` True where a sample was filled by interpolation.
        missing: ``(n, m)`` True where a sample is still missing (long gap).
        warnings: human-readable notes (e.g. which markers had gaps filled).
    """

    frames: np.ndarray
    time: np.ndarray
    frequency: float
    marker_names: list[str]
    positions: np.ndarray
    positions_back: np.ndarray
    back_origin: np.ndarray
    back_rotation: np.ndarray
    hand_position: np.ndarray
    hand_position_back: np.ndarray
    hand_orientation_back: np.ndarray
    hand_velocity: np.ndarray
    hand_velocity_back: np.ndarray
    interpolated: np.ndarray
    missing: np.ndarray
    warnings: list[str] = field(default_factory=list)

    @property
    def n_frames(self) -> int:
        return int(len(self.frames))

    def marker_back(self, name: str) -> np.ndarray:
        """``(n, 3)`` positions of one marker in the back frame."""
        return self.positions_back[:, self.marker_names.index(name), :]


def back_frame(top: np.ndarray, right: np.ndarray, left: np.ndarray):
    """Origin ``(n, 3)`` and rotation ``(n, 3, 3)`` (columns x, y, z) of the back frame.

    Rows where a marker is missing or the markers are collinear are NaN.
    """
    origin = (top + right + left) / 3.0
    y = left - right
    y = y / np.linalg.norm(y, axis=1, keepdims=True)
    up = top - 0.5 * (left + right)
    z = up - np.sum(up * y, axis=1, keepdims=True) * y
    zn = np.linalg.norm(z, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.where(zn > 1e-9, z / zn, np.nan)
    x = np.cross(y, z)
    rot = np.stack([x, y, z], axis=2)
    return origin, rot


def to_frame(points: np.ndarray, origin: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Express world points ``(n, 3)`` or ``(n, m, 3)`` in a moving frame (origin, rotation)."""
    if points.ndim == 2:
        return np.einsum("nji,nj->ni", rotation, points - origin)
    return np.einsum("nji,nmj->nmi", rotation, points - origin[:, None, :])


def rotation_to_quaternion(rot: np.ndarray) -> np.ndarray:
    """``(n, 3, 3)`` rotation matrices to ``(n, 4)`` unit quaternions ``(w, x, y, z)``, sign-continuous."""
    from scipy.spatial.transform import Rotation

    n = len(rot)
    q = np.full((n, 4), np.nan)
    ok = np.isfinite(rot).all(axis=(1, 2))
    if ok.any():
        xyzw = Rotation.from_matrix(rot[ok]).as_quat()
        q[ok] = xyzw[:, [3, 0, 1, 2]]
    prev = None
    for i in range(n):  # sign continuity: q and -q are the same rotation
        if not ok[i]:
            continue
        if prev is not None and np.dot(q[i], prev) < 0:
            q[i] = -q[i]
        prev = q[i]
    return q


def velocity(x: np.ndarray, frequency: float, window_s: float = DEFAULT_VELOCITY_WINDOW_S) -> np.ndarray:
    """Time derivative of ``(n, d)`` samples (units per second) by a Savitzky-Golay filter."""
    x = np.asarray(x, dtype=float)
    n = len(x)
    win = max(5, int(round(window_s * frequency)) | 1)
    if n < 3:
        raise PreprocessError(f"need at least 3 samples to compute velocities, got {n}")
    if win > n:
        win = n if n % 2 == 1 else n - 1
    order = min(2, win - 1)
    return savgol_filter(x, win, order, deriv=1, axis=0) * frequency


def _require(rec: MocapRecording, names) -> None:
    absent = [n for n in names if n not in rec.marker_names]
    if absent:
        raise PreprocessError(
            f"the recording has no marker(s) {absent}; it has {rec.marker_names}"
        )
    never = [n for n in names if n in rec.missing_markers()]
    if never:
        raise PreprocessError(f"marker(s) {never} are never visible in the recording")


def _check_arguments(rec: MocapRecording, hand_markers: tuple, back_markers: tuple, max_gap_s: float) -> None:
    """The arguments of :func:`preprocess` make sense and the recording has the markers they name."""
    if not np.isfinite(max_gap_s) or max_gap_s < 0:
        raise PreprocessError(f"the longest gap to fill must be a number of seconds >= 0, got {max_gap_s}")
    if len(back_markers) != 3:
        raise PreprocessError(f"the back frame needs three markers (top, right, left), got {back_markers}")
    if len(hand_markers) < 1:
        raise PreprocessError("at least one hand marker is needed")
    if rec.n_frames < 3:
        raise PreprocessError(f"the recording has {rec.n_frames} frames; at least 3 are needed")
    _require(rec, hand_markers + back_markers)


def _require_filled(rec: MocapRecording, missing: np.ndarray, markers: tuple, max_gap_s: float) -> None:
    """Every marker of ``markers`` is visible (or filled) in every frame after gap filling."""
    for j in (rec.marker_index(n) for n in markers):
        if missing[:, j].any():
            bad = rec.frames[missing[:, j]]
            raise PreprocessError(
                f"marker {rec.marker_names[j]!r} is missing at {len(bad)} frames "
                f"(first {int(bad[0])}, last {int(bad[-1])}) in gaps longer than {max_gap_s} s "
                "or at the recording's ends; crop the recording or raise max_gap_s"
            )


def preprocess(
    rec: MocapRecording,
    hand_markers=HAND_MARKERS,
    back_markers=BACK_MARKERS,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    velocity_window_s: float = DEFAULT_VELOCITY_WINDOW_S,
) -> Preprocessed:
    """Gap filling, back frame, hand pose and velocities of one recording.

    Raises:
        PreprocessError: a hand or back marker is absent or never visible, the recording has
            fewer than 3 frames, or hand/back markers still have gaps longer than ``max_gap_s``
            inside the recording (the message names the marker and the frames).
    """
    hand_markers, back_markers = tuple(hand_markers), tuple(back_markers)
    _check_arguments(rec, hand_markers, back_markers, max_gap_s)
    rec, warnings = reject_outliers(rec)  # a single 10 m glitch would otherwise become a segment
    filled = fill_gaps(rec, max_gap_s)  # short gaps by a local cubic spline; long and edge gaps stay NaN
    pos, interp = filled.recording.positions, filled.filled_mask
    missing = np.isnan(pos).any(axis=2)
    for j, name in enumerate(rec.marker_names):
        if interp[:, j].any():
            warnings.append(f"{name}: {int(interp[:, j].sum())} samples interpolated")
    _require_filled(rec, missing, hand_markers + back_markers, max_gap_s)
    top, right, left = (pos[:, rec.marker_index(n), :] for n in back_markers)
    origin, rot = back_frame(top, right, left)
    if not np.isfinite(rot).all():
        raise PreprocessError("the back markers are collinear or coincide: no back frame can be built")
    positions_back = to_frame(pos, origin, rot)
    hidx = [rec.marker_index(n) for n in hand_markers]
    hand = pos[:, hidx, :].mean(axis=1)
    hand_back = positions_back[:, hidx, :].mean(axis=1)
    if len(hand_markers) >= 3:
        _, hrot = back_frame(*(positions_back[:, i, :] for i in hidx[:3]))
        quat = rotation_to_quaternion(hrot)
    else:
        quat = np.tile([1.0, 0.0, 0.0, 0.0], (rec.n_frames, 1))
        warnings.append("fewer than 3 hand markers: hand orientation is not observable (identity)")
    return Preprocessed(
        frames=rec.frames.copy(),
        time=rec.time.copy(),
        frequency=rec.frequency,
        marker_names=list(rec.marker_names),
        positions=pos,
        positions_back=positions_back,
        back_origin=origin,
        back_rotation=rot,
        hand_position=hand,
        hand_position_back=hand_back,
        hand_orientation_back=quat,
        hand_velocity=velocity(hand, rec.frequency, velocity_window_s),
        hand_velocity_back=velocity(hand_back, rec.frequency, velocity_window_s),
        interpolated=interp,
        missing=missing,
        warnings=warnings,
    )
