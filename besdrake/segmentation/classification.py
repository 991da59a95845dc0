"""1-NN classification of movement segments (Gutzeit & Kirchner 2016; paper section 2.2).

A segment is described by the time-normalised trajectories of a few markers in the
demonstrator's back frame; segments are compared by Euclidean distance and labelled by their
nearest training segment (scikit-learn's ``KNeighborsClassifier(n_neighbors=1)``).

The feature vector of a segment (:class:`SegmentFeatures`) concatenates, for the chosen
markers, ``n_points`` samples evenly spaced in normalised time of

* the position in the back frame (``position_weight``),
* the position relative to the segment's first sample (``relative_weight``),
* the velocity in normalised time divided by the segment's peak hand speed
  (``velocity_weight``; duration-free, so only the shape of the speed profile counts),

the segment duration in seconds (``duration_weight``) and the logarithm of the hand's path
length in metres (``path_length_weight``: an idle segment moves centimetres, a movement tens
of centimetres, wherever it happens). Positions are in metres; the weights make the parts
commensurable. ``*_part`` labels (a movement a labeller split in two)
are mapped to their parent class by :func:`normalise_label` when ``part_policy="parent"``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin
from sklearn.neighbors import KNeighborsClassifier

from besdrake.mocap.preprocess import HAND_MARKERS, Preprocessed, velocity

PART_SUFFIX = "_part"
#: Feature settings chosen on the pick-and-place data (hand + object, normalised velocity).
DEFAULT_VELOCITY_WEIGHT = 0.3
#: Weight of the log hand path length (separates idle from movements).
DEFAULT_PATH_LENGTH_WEIGHT = 3.0


class ClassificationError(ValueError):
    """Segments that cannot be classified (empty, too short, NaN, missing marker)."""


@dataclass
class MovementSegment:
    """One segment of a preprocessed recording (back-frame trajectories, SI units).

    Attributes:
        marker_names: names of the ``positions_back`` columns.
        positions_back: ``(L, m, 3)`` metres in the back frame.
        frequency: Hz.
        start_frame, end_frame: the file's frame numbers (inclusive).
        label: manual label if known.
    """

    marker_names: list[str]
    positions_back: np.ndarray
    frequency: float
    start_frame: int = -1
    end_frame: int = -1
    label: str | None = None

    @property
    def duration(self) -> float:
        return (len(self.positions_back) - 1) / self.frequency

    def marker(self, name: str) -> np.ndarray:
        if name == "hand":
            idx = [self.marker_names.index(n) for n in HAND_MARKERS if n in self.marker_names]
            if not idx:
                raise ClassificationError(f"no hand markers {HAND_MARKERS} in {self.marker_names}")
            return self.positions_back[:, idx, :].mean(axis=1)
        if name not in self.marker_names:
            raise ClassificationError(f"segment has no marker {name!r}; it has {self.marker_names}")
        return self.positions_back[:, self.marker_names.index(name), :]


def extract_segment(pre: Preprocessed, start_index: int, end_index: int, label: str | None = None) -> MovementSegment:
    """The samples ``start_index..end_index`` (inclusive row indices) of a preprocessed recording."""
    if not 0 <= start_index < end_index < pre.n_frames:
        raise ClassificationError(
            f"segment rows {start_index}..{end_index} are not inside the recording (0..{pre.n_frames - 1})"
        )
    return MovementSegment(
        marker_names=list(pre.marker_names),
        positions_back=pre.positions_back[start_index : end_index + 1].copy(),
        frequency=pre.frequency,
        start_frame=int(pre.frames[start_index]),
        end_frame=int(pre.frames[end_index]),
        label=label,
    )


def normalise_label(label: str, part_policy: str = "parent") -> str:
    """``approach_right_part`` -> ``approach_right`` for ``part_policy="parent"``; else unchanged."""
    if part_policy == "parent" and label.endswith(PART_SUFFIX):
        return label[: -len(PART_SUFFIX)]
    return label


def _resample(x: np.ndarray, n_points: int) -> np.ndarray:
    L = len(x)
    src = np.linspace(0.0, 1.0, L)
    dst = np.linspace(0.0, 1.0, n_points)
    return np.stack([np.interp(dst, src, x[:, j]) for j in range(x.shape[1])], axis=1)


@dataclass
class SegmentFeatures:
    """Feature map of segments (see the module docstring)."""

    markers: tuple[str, ...] = ("hand",)
    n_points: int = 20
    position_weight: float = 1.0
    relative_weight: float = 0.0
    velocity_weight: float = 0.0
    duration_weight: float = 0.0
    velocity_normalisation: str = "peak"
    path_length_weight: float = 0.0

    def transform_one(self, seg: MovementSegment) -> np.ndarray:
        if len(seg.positions_back) < 3:
            raise ClassificationError(
                f"segment {seg.start_frame}..{seg.end_frame} has {len(seg.positions_back)} samples; at least 3 are needed"
            )
        for name in set(self.markers) | ({"hand"} if self.velocity_weight else set()):
            if not np.isfinite(seg.marker(name)).all():
                raise ClassificationError(
                    f"marker {name!r} has missing samples in segment {seg.start_frame}..{seg.end_frame}"
                )
        parts = []
        scale = 1.0
        if self.velocity_weight:
            if self.velocity_normalisation == "peak":
                hv = self._velocity(seg.marker("hand"), seg)
                scale = max(float(np.max(np.linalg.norm(hv, axis=1))), 1e-6)
            elif self.velocity_normalisation != "none":
                raise ValueError(f"velocity_normalisation must be 'peak' or 'none', got {self.velocity_normalisation!r}")
        for name in self.markers:
            x = seg.marker(name)
            xs = _resample(x, self.n_points)
            if self.position_weight:
                parts.append(self.position_weight * xs.ravel())
            if self.relative_weight:
                parts.append(self.relative_weight * (xs - xs[0]).ravel())
            if self.velocity_weight:
                parts.append(self.velocity_weight * (self._velocity(x, seg) / scale).ravel())
        if self.duration_weight:
            parts.append(np.array([self.duration_weight * seg.duration]))
        if self.path_length_weight:
            hand = seg.marker("hand")
            length = float(np.sum(np.linalg.norm(np.diff(hand, axis=0), axis=1)))
            parts.append(np.array([self.path_length_weight * np.log(max(length, 1e-3))]))
        return np.concatenate(parts)

    def _velocity(self, x: np.ndarray, seg: MovementSegment) -> np.ndarray:
        """Velocity at the ``n_points`` normalised times: per unit normalised time for
        ``"peak"`` normalisation (duration-free), in m/s for ``"none"``."""
        fine = _resample(x, 4 * self.n_points)
        v = np.gradient(fine, axis=0) * (len(fine) - 1)  # d x / d tau
        if self.velocity_normalisation == "none":
            v = v / max(seg.duration, 1e-9)
        return _resample(v, self.n_points)

    def transform(self, segments) -> np.ndarray:
        segments = list(segments)
        if not segments:
            raise ClassificationError("no segments given")
        return np.stack([self.transform_one(s) for s in segments])


class SegmentClassifier(ClassifierMixin, BaseEstimator):
    """1-NN movement classifier on :class:`SegmentFeatures` (scikit-learn estimator).

    ``fit(segments, labels)`` takes a list of :class:`MovementSegment` and their labels;
    ``predict(segments)`` returns labels. ``*_part`` labels are mapped by ``part_policy``
    (``"parent"``: to the parent class; ``"own"``: kept as their own class).
    """

    def __init__(
        self,
        markers="auto",
        n_points: int = 20,
        position_weight: float = 1.0,
        relative_weight: float = 0.0,
        velocity_weight: float = DEFAULT_VELOCITY_WEIGHT,
        duration_weight: float = 0.0,
        velocity_normalisation: str = "peak",
        path_length_weight: float = DEFAULT_PATH_LENGTH_WEIGHT,
        part_policy: str = "parent",
    ) -> None:
        self.markers = markers
        self.n_points = n_points
        self.position_weight = position_weight
        self.relative_weight = relative_weight
        self.velocity_weight = velocity_weight
        self.duration_weight = duration_weight
        self.velocity_normalisation = velocity_normalisation
        self.path_length_weight = path_length_weight
        self.part_policy = part_policy

    def _resolve_markers(self, segments) -> tuple[str, ...]:
        """``markers="auto"``: the hand plus the tasks' object markers (:func:`besdrake.task.object_markers`, e.g. the
        manipulated box) seen in every sample of every training segment; without such a marker, the hand and the
        elbow."""
        if self.markers != "auto":
            return tuple(self.markers)

        def usable(name: str) -> bool:
            for seg in segments:
                if name not in seg.marker_names:
                    return False
                if not np.isfinite(seg.positions_back[:, seg.marker_names.index(name), :]).all():
                    return False
            return True

        from besdrake.task import object_markers

        objects = [m for m in object_markers() if usable(m)]
        if objects:
            return ("hand", *objects)
        return ("hand", "Elbow") if usable("Elbow") else ("hand",)

    @property
    def features(self) -> SegmentFeatures:
        markers = getattr(self, "markers_", None) or tuple(self.markers)
        return SegmentFeatures(
            tuple(markers), int(self.n_points), self.position_weight, self.relative_weight,
            self.velocity_weight, self.duration_weight, self.velocity_normalisation,
            self.path_length_weight,
        )

    def fit(self, segments, labels):
        segments, labels = list(segments), list(labels)
        if len(segments) != len(labels):
            raise ClassificationError(f"{len(segments)} segments but {len(labels)} labels")
        if self.part_policy not in ("parent", "own"):
            raise ValueError(f"part_policy must be 'parent' or 'own', got {self.part_policy!r}")
        if not segments:
            raise ClassificationError("no training segments given")
        self.markers_ = self._resolve_markers(segments)
        X = self.features.transform(segments)
        y = np.array([normalise_label(str(l), self.part_policy) for l in labels])
        self._fit_features(X, y)
        return self

    def _fit_features(self, X: np.ndarray, y: np.ndarray) -> None:
        self.X_train_, self.y_train_ = X, y
        self.knn_ = KNeighborsClassifier(n_neighbors=1).fit(X, y)
        self.classes_ = self.knn_.classes_

    def to_json(self) -> dict:
        """Parameters and training features as JSON-serialisable data (see :meth:`from_json`)."""
        if not hasattr(self, "knn_"):
            raise ClassificationError("the classifier is not fitted")
        params = self.get_params()
        params["markers"] = list(self.markers_)
        return {
            "format": "besdrake.segment_classifier/1",
            "params": params,
            "X": self.X_train_.tolist(),
            "y": [str(v) for v in self.y_train_],
        }

    @classmethod
    def from_json(cls, data: dict) -> "SegmentClassifier":
        if not isinstance(data, dict) or data.get("format") != "besdrake.segment_classifier/1":
            raise ClassificationError("not a besdrake segment classifier file (format besdrake.segment_classifier/1)")
        params = dict(data["params"])
        params["markers"] = tuple(params["markers"])
        clf = cls(**params)
        clf.markers_ = tuple(params["markers"])
        X = np.asarray(data["X"], dtype=float)
        y = np.asarray(data["y"])
        if X.ndim != 2 or len(X) != len(y) or not np.isfinite(X).all():
            raise ClassificationError("classifier file: X must be a finite 2-D array with one label per row")
        clf._fit_features(X, y)
        return clf

    def predict(self, segments) -> np.ndarray:
        if not hasattr(self, "knn_"):
            raise ClassificationError("the classifier is not fitted; call fit(segments, labels) first")
        return self.knn_.predict(self.features.transform(segments))

    def score(self, segments, labels, sample_weight=None) -> float:
        y = np.array([normalise_label(str(l), self.part_policy) for l in labels])
        return float(np.mean(self.predict(segments) == y))
