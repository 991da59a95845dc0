"""Shared pieces of the segmenters: result dataclass, input handling, errors."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from besdrake.mocap.preprocess import Preprocessed, preprocess, velocity
from besdrake.mocap.recording import MocapRecording


class SegmentationError(ValueError):
    """Input that cannot be segmented (too short, NaN samples, impossible parameters)."""


#: Which preprocessed velocity the segmenters use for recordings.
SIGNALS = ("hand_velocity", "hand_velocity_back")


@dataclass
class SegmentationResult:
    """Interior borders of a segmentation of ``n_samples`` samples.

    ``borders`` are sample indices ``b`` (sorted, ``0 < b < n_samples``): a segment ends and the
    next begins at sample ``b`` (adjacent segments share the border sample, as in the
    ``*_manually_segmented.json`` layout).
    """

    borders: np.ndarray
    n_samples: int

    def segments(self) -> list[tuple[int, int]]:
        """``(start, end)`` sample indices, ``end`` inclusive and equal to the next start."""
        edges = [0, *[int(b) for b in self.borders], self.n_samples - 1]
        return [(edges[i], edges[i + 1]) for i in range(len(edges) - 1)]


def result_from_borders(borders, n_samples: int) -> SegmentationResult:
    b = np.unique(np.asarray(borders, dtype=int))
    b = b[(b > 0) & (b < n_samples - 1)]
    return SegmentationResult(borders=b, n_samples=int(n_samples))


class SegmenterMixin:
    """``fit(X)`` for segmenters: ``X`` is a :class:`MocapRecording`, a :class:`Preprocessed`
    recording or an ``(n, d)`` array (positions or velocities, see ``input``).

    Subclasses implement ``_segment(V, frequency) -> SegmentationResult`` on velocities.
    """

    signal: str = "hand_velocity"
    input: str = "position"
    frequency: float = 60.0
    velocity_window_s: float = 0.15

    def _velocities(self, X, frequency: float | None):
        frames = None
        if isinstance(X, MocapRecording):
            X = preprocess(X, velocity_window_s=self.velocity_window_s)
        if isinstance(X, Preprocessed):
            sig = getattr(self, "signal", "hand_velocity")
            if sig not in SIGNALS:
                raise ValueError(f"signal must be one of {SIGNALS}, got {sig!r}")
            return getattr(X, sig), X.frequency, X.frames
        freq = float(frequency if frequency is not None else self.frequency)
        arr = np.asarray(X, dtype=float)
        if arr.ndim == 1:
            arr = arr[:, None]
        if arr.ndim != 2 or arr.shape[0] == 0:
            raise SegmentationError(f"expected an (n_samples, n_dims) array, got shape {arr.shape}")
        if not np.isfinite(arr).all():
            bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
            raise SegmentationError(
                f"the input has NaN/inf at {len(bad)} samples (first index {bad[0]}); "
                "fill gaps first (besdrake.mocap.gaps.fill_gaps) or crop the recording"
            )
        if self.input == "position":
            if arr.shape[0] < 5:
                raise SegmentationError(f"a recording of {arr.shape[0]} samples is too short to segment")
            arr = velocity(arr, freq, self.velocity_window_s)
        return arr, freq, frames

    def fit(self, X, y=None, frequency: float | None = None):
        """Segment ``X``; sets ``result_``, ``borders_``, ``segments_``, ``frames_`` (or None)."""
        V, freq, frames = self._velocities(X, frequency)
        self.result_ = self._segment(V, freq)
        self.borders_ = self.result_.borders
        self.segments_ = self.result_.segments()
        self.frames_ = frames
        self.frequency_ = freq
        return self

    def fit_predict(self, X, y=None, frequency: float | None = None) -> np.ndarray:
        """Segment ``X`` and return the interior border indices."""
        return self.fit(X, frequency=frequency).borders_

    def json_params(self) -> dict:
        """:meth:`get_params` with parameter objects as their ``to_dict()`` (JSON-ready)."""
        return {k: (v.to_dict() if hasattr(v, "to_dict") else v) for k, v in self.get_params().items()}

    def get_params(self, deep: bool = True) -> dict:
        import inspect

        names = [p for p in inspect.signature(type(self).__init__).parameters if p != "self"]
        return {n: getattr(self, n) for n in names}

    def set_params(self, **params):
        valid = self.get_params()
        for k, v in params.items():
            if k not in valid:
                raise ValueError(f"unknown parameter {k!r} for {type(self).__name__}; valid: {sorted(valid)}")
            setattr(self, k, v)
        return self

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"
