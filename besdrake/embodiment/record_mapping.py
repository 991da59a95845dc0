"""Record mapping: a demonstrated movement segment as hand poses in the demonstrator's back frame.

The paper (section 2.3.2) reduces marker positions to end-effector poses in a reference frame on
the teacher: the back. :func:`besdrake.mocap.preprocess.preprocess` builds that frame and the hand
pose; this module cuts one segment out and fixes the hand axis that maps to the robot's tool axis.

Hand axis convention: preprocessing builds the hand frame from the three hand markers like the
back frame (``y`` from ``Hand right`` to ``Hand left``, ``z`` towards ``Hand top``), so with the
marker plate on the back of the hand its ``x`` axis is the plate normal pointing out of the palm.
A robot's tool need not be a hand: the robot file's ``mapping.tool_axis`` (e.g. an open tool's
opening, +z of its frame) plays the palm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from besdrake.mocap.preprocess import Preprocessed


class RecordMappingError(ValueError):
    """A segment that cannot be mapped to hand poses (too short, NaN samples, out of range)."""


#: Minimum number of samples of a segment that can be imitated.
MIN_SAMPLES = 5


@dataclass
class HandTrajectory:
    """Hand poses of one demonstrated segment in the back frame (SI units).

    Attributes:
        t: ``(n,)`` seconds from the segment's start.
        position: ``(n, 3)`` hand centre in the back frame, m.
        quaternion: ``(n, 4)`` hand orientation ``(w, x, y, z)`` in the back frame.
        palm_axis: ``(n, 3)`` unit vector of the palm normal in the back frame (maps to the
            robot's tool axis).
        frames: ``(n,)`` the recording's frame numbers (for reports).
    """

    t: np.ndarray
    position: np.ndarray
    quaternion: np.ndarray
    palm_axis: np.ndarray
    frames: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.t)
        if n < MIN_SAMPLES:
            raise RecordMappingError(f"a segment needs at least {MIN_SAMPLES} samples to be imitated, got {n}")
        for name, arr, width in (("position", self.position, 3), ("quaternion", self.quaternion, 4), ("palm_axis", self.palm_axis, 3)):
            if arr.shape != (n, width):
                raise RecordMappingError(f"{name} must have shape ({n}, {width}), got {arr.shape}")
        bad = ~np.isfinite(np.hstack([self.t[:, None], self.position, self.quaternion, self.palm_axis])).all(axis=1)
        if bad.any():
            raise RecordMappingError(
                f"the segment has {int(bad.sum())} samples with NaN (first at frame {int(self.frames[bad][0])}): "
                "fill the gaps before imitation"
            )
        if np.any(np.diff(self.t) <= 0):
            raise RecordMappingError("segment time stamps must increase strictly")

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    def smoothed(self, window_s: float = 0.07) -> "HandTrajectory":
        """Low-pass filtered copy (Savitzky-Golay, order 3): mocap noise on a hand plate a few
        centimetres wide makes the orientation jitter by degrees, which inverse kinematics would
        otherwise chase with the wrist."""
        from scipy.signal import savgol_filter

        dt = float(np.median(np.diff(self.t)))
        win = int(round(window_s / dt)) | 1
        if win < 5 or win > len(self.t):
            return self
        pos = savgol_filter(self.position, win, 3, axis=0)
        axis = savgol_filter(self.palm_axis, win, 3, axis=0)
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        return HandTrajectory(t=self.t, position=pos, quaternion=self.quaternion, palm_axis=axis, frames=self.frames)

    def resample(self, n: int) -> "HandTrajectory":
        """``n`` poses evenly spaced in time (positions linear, orientations by slerp)."""
        from scipy.spatial.transform import Slerp

        t_new = np.linspace(self.t[0], self.t[-1], n)
        pos = np.stack([np.interp(t_new, self.t, self.position[:, k]) for k in range(3)], axis=1)
        rot = Slerp(self.t, Rotation.from_quat(self.quaternion[:, [1, 2, 3, 0]]))(t_new)
        quat = rot.as_quat()[:, [3, 0, 1, 2]]
        axis = rot.apply(_PALM_AXIS_IN_HAND)
        frames = np.round(np.interp(t_new, self.t, self.frames)).astype(int)
        return HandTrajectory(t=t_new - t_new[0], position=pos, quaternion=quat, palm_axis=axis, frames=frames)


#: The palm normal in preprocessing's hand frame (see the module docstring).
_PALM_AXIS_IN_HAND = np.array([1.0, 0.0, 0.0])


def hand_trajectory(pre: Preprocessed, start_frame: int, end_frame: int) -> HandTrajectory:
    """Hand poses between two frame numbers (inclusive) of a preprocessed recording."""
    frames = np.asarray(pre.frames)
    if start_frame >= end_frame:
        raise RecordMappingError(f"segment [{start_frame}, {end_frame}] is empty")
    if start_frame < frames[0] or end_frame > frames[-1]:
        raise RecordMappingError(
            f"segment [{start_frame}, {end_frame}] lies outside the recording's frames [{frames[0]}, {frames[-1]}]"
        )
    sel = (frames >= start_frame) & (frames <= end_frame)
    t = pre.time[sel] - pre.time[sel][0]
    quat = pre.hand_orientation_back[sel]
    ok = np.isfinite(quat).all(axis=1)
    axis = np.full((int(sel.sum()), 3), np.nan)
    if ok.any():
        axis[ok] = Rotation.from_quat(quat[ok][:, [1, 2, 3, 0]]).apply(_PALM_AXIS_IN_HAND)
    return HandTrajectory(
        t=t, position=pre.hand_position_back[sel], quaternion=quat, palm_axis=axis, frames=frames[sel]
    )
