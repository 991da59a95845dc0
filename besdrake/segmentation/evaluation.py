"""Scoring segmentations against manual ones, and loading labelled recording folders.

Interior borders of a manual segmentation (the definition used for scoring, mode
``"starts_and_ends"``): the start and end frames of every labelled segment (``*_part``
sub-segments and ``idle`` included, so the ends of an unlabelled pause are two borders),
without the recording's first and last frame; borders closer than ``merge_s`` (0.1 s, e.g. a
part ending one frame before its parent) are merged into their mean. Two looser definitions
are reported beside it: ``"starts"`` (segment starts only: a pause belongs to the movement
before it) and ``"midgap"`` (one border in the middle of each unlabelled pause). Predicted and
manual borders are matched one-to-one (a maximum matching, ties broken by smallest total
distance) within a tolerance.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from besdrake.mocap.qualisys import read_segmentation, read_tsv
from besdrake.mocap.recording import MocapRecording
from besdrake.mocap.segments_io import Segment, segmentation_path

BORDER_DEFINITION = (
    "interior borders = start and end frames of every manual segment (parts and idle included), "
    "excluding the recording's first and last frame, borders closer than 0.1 s merged; "
    "one-to-one matching within the tolerance"
)


BORDER_MODES = ("starts_and_ends", "starts", "midgap")


def manual_borders(segments: list[Segment], first_frame: int, last_frame: int, frequency: float,
                   merge_s: float = 0.1, include_parts: bool = True, mode: str = "starts_and_ends") -> np.ndarray:
    """Interior border frame numbers of a manual segmentation (see the module docstring).

    ``mode``: ``"starts_and_ends"`` (both ends of an unlabelled pause are borders), ``"starts"``
    (only segment starts: a pause belongs to the movement before it), ``"midgap"`` (one border
    in the middle of each pause).
    """
    if mode not in BORDER_MODES:
        raise ValueError(f"mode must be one of {BORDER_MODES}, got {mode!r}")
    segs = [s for s in segments if include_parts or not s.label.endswith("_part")]
    b = []
    if mode == "starts_and_ends":
        for s in segs:
            b += [s.start_frame, s.end_frame]
    elif mode == "starts":
        b = [s.start_frame for s in segs]
    else:
        starts = sorted({s.start_frame for s in segs})
        ends = sorted({s.end_frame for s in segs})
        for st in starts:
            prev = [e for e in ends if e <= st]
            if prev and st - prev[-1] > merge_s * frequency:
                b.append(0.5 * (st + prev[-1]))
            else:
                b.append(st)
    b = np.array(sorted(b), dtype=float)
    merge = merge_s * frequency
    margin = 0.5 * merge
    b = b[(b > first_frame + margin) & (b < last_frame - margin)]
    out: list[list[float]] = []
    for x in b:
        if out and x - out[-1][-1] <= merge:
            out[-1].append(x)
        else:
            out.append([x])
    return np.array([round(float(np.mean(g))) for g in out], dtype=int)


@dataclass
class BorderScore:
    """Counts and scores of one border matching."""

    tolerance_s: float
    n_true: int
    n_pred: int
    n_matched: int

    @property
    def precision(self) -> float:
        return self.n_matched / self.n_pred if self.n_pred else 0.0

    @property
    def recall(self) -> float:
        return self.n_matched / self.n_true if self.n_true else 0.0

    @property
    def f1(self) -> float:
        p, r = self.precision, self.recall
        return 2 * p * r / (p + r) if p + r > 0 else 0.0

    def __add__(self, other: "BorderScore") -> "BorderScore":
        return BorderScore(self.tolerance_s, self.n_true + other.n_true, self.n_pred + other.n_pred,
                           self.n_matched + other.n_matched)

    def to_dict(self) -> dict:
        d = asdict(self)
        d.update(precision=self.precision, recall=self.recall, f1=self.f1)
        return d


def match_borders(pred, true, tolerance: float) -> int:
    """Number of one-to-one matches between ``pred`` and ``true`` (same units) within ``tolerance``."""
    pred, true = np.asarray(pred, float), np.asarray(true, float)
    if len(pred) == 0 or len(true) == 0:
        return 0
    dist = np.abs(pred[:, None] - true[None, :])
    big = 1e6 * (1 + dist.max())
    cost = np.where(dist <= tolerance + 1e-9, dist - big, 0.0)
    r, c = linear_sum_assignment(cost)
    return int(np.sum(dist[r, c] <= tolerance + 1e-9))


def score_borders(pred_frames, true_frames, frequency: float, tolerance_s: float) -> BorderScore:
    m = match_borders(pred_frames, true_frames, tolerance_s * frequency)
    return BorderScore(tolerance_s, len(true_frames), len(pred_frames), m)


@dataclass
class LabelledRecording:
    """A recording and its manual segmentation."""

    path: Path
    recording: MocapRecording
    segments: list[Segment]


def labelled_recordings(directory: str | Path) -> list[LabelledRecording]:
    """All ``*.tsv`` recordings in ``directory`` that have a ``*_manually_segmented.json`` beside them."""
    directory = Path(directory)
    if not directory.is_dir():
        raise FileNotFoundError(f"{directory} is not a directory")
    out = []
    for tsv in sorted(directory.glob("*.tsv")):
        seg = segmentation_path(tsv)
        if seg.exists():
            out.append(LabelledRecording(tsv, read_tsv(tsv), read_segmentation(seg)))
    if not out:
        raise FileNotFoundError(f"{directory} holds no *.tsv recording with a *_manually_segmented.json beside it")
    return out


PART_POLICY = (
    "*_part sub-segments overlap their labelled parent: they are left out of training and testing "
    "(the parent segment is used); labels are the parent classes"
)


def labelled_segments(recordings: list[LabelledRecording], include_parts: bool = False):
    """``(segments, labels)`` of the manual segments of labelled recordings (parts left out by default)."""
    from besdrake.mocap.preprocess import preprocess
    from besdrake.segmentation.classification import extract_segment

    segments, labels = [], []
    for rec in recordings:
        pre = preprocess(rec.recording)
        for s in rec.segments:
            if s.label.endswith("_part") and not include_parts:
                continue
            try:
                a, b = pre_index(pre.frames, s.start_frame), pre_index(pre.frames, s.end_frame)
            except IndexError as err:
                raise ValueError(f"{rec.path}: segment {s}: {err}") from None
            segments.append(extract_segment(pre, a, b, s.label))
            labels.append(s.label)
    return segments, labels


def matching_segments(found_frames: np.ndarray, true: list[Segment], frequency: float, tolerance_s: float = 0.2,
                      label: str | None = None) -> list[tuple[Segment, int | None]]:
    """For each manual segment (only those labelled ``label`` when given): the index of the first found
    segment whose start and end frames both lie within ``tolerance_s`` of it, or None.

    ``found_frames``: ``(k, 2)`` start and end frame numbers of the found segments."""
    found_frames = np.asarray(found_frames, dtype=float).reshape(-1, 2)
    tol = tolerance_s * frequency
    out = []
    for s in true:
        if label is not None and s.label != label:
            continue
        hit = np.flatnonzero((np.abs(found_frames[:, 0] - s.start_frame) <= tol) & (np.abs(found_frames[:, 1] - s.end_frame) <= tol))
        out.append((s, int(hit[0]) if len(hit) else None))
    return out


def pre_index(frames: np.ndarray, frame: int) -> int:
    """Row of ``frame`` in a frame-number array (nearest row, clipped, for labels on dropped frames)."""
    i = int(np.searchsorted(frames, frame))
    if frame < frames[0] - 1 or frame > frames[-1] + 1:
        raise IndexError(f"frame {frame} is outside the recording (frames {frames[0]}..{frames[-1]})")
    return int(np.clip(i, 0, len(frames) - 1))


@dataclass
class SegmentationEvaluation:
    """Border scores of a segmenter over labelled recordings, with its CPU time.

    ``scores[mode][tolerance_s]`` for every border definition in :data:`BORDER_MODES`.
    """

    method: str
    params: dict
    scores: dict
    cpu_s: float
    data_s: float

    def f1(self, tolerance_s: float, mode: str = "starts_and_ends") -> float:
        return self.scores[mode][float(tolerance_s)].f1

    def to_dict(self) -> dict:
        return {
            "method": self.method,
            "params": self.params,
            "border_definition": BORDER_DEFINITION,
            "scores": {str(t): s.to_dict() for t, s in self.scores["starts_and_ends"].items()},
            "scores_other_definitions": {
                m: {str(t): s.to_dict() for t, s in v.items()} for m, v in self.scores.items() if m != "starts_and_ends"
            },
            "cpu_s": self.cpu_s,
            "data_s": self.data_s,
            "times_faster_than_real_time": self.data_s / self.cpu_s if self.cpu_s > 0 else None,
        }


def evaluate_segmenter(segmenter, recordings: list[LabelledRecording], tolerances=(0.1, 0.2),
                       preprocessed: dict | None = None) -> SegmentationEvaluation:
    """Fit ``segmenter`` on every recording and score its interior borders (CPU time of ``fit`` only).

    ``preprocessed`` may map ``str(path)`` to a :class:`~besdrake.mocap.preprocess.Preprocessed`
    recording to skip preprocessing.
    """
    import time

    from besdrake.mocap.preprocess import preprocess

    scores = {m: {float(t): BorderScore(float(t), 0, 0, 0) for t in tolerances} for m in BORDER_MODES}
    cpu = data = 0.0
    for rec in recordings:
        pre = preprocessed[str(rec.path)] if preprocessed else preprocess(rec.recording)
        t0 = time.process_time()
        segmenter.fit(pre)
        cpu += time.process_time() - t0
        data += pre.n_frames / pre.frequency
        pred = pre.frames[segmenter.borders_]
        for mode in BORDER_MODES:
            true = manual_borders(rec.segments, int(pre.frames[0]), int(pre.frames[-1]), pre.frequency, mode=mode)
            for t in scores[mode]:
                scores[mode][t] = scores[mode][t] + score_borders(pred, true, pre.frequency, t)
    params = segmenter.json_params() if hasattr(segmenter, "json_params") else segmenter.get_params()
    return SegmentationEvaluation(type(segmenter).__name__, params, scores, cpu, data)


def evaluate_classifier(classifier, train: list[LabelledRecording], test: list[LabelledRecording]) -> dict:
    """Fit on the manual segments of ``train``, score on those of ``test``: accuracy, per class, confusions."""
    Xtr, ytr = labelled_segments(train)
    Xte, yte = labelled_segments(test)
    classifier.fit(Xtr, ytr)
    pred = classifier.predict(Xte)
    yte = np.array(yte)
    classes = sorted(set(yte))
    per_class = {c: float(np.mean(pred[yte == c] == c)) for c in classes}
    confusions: dict[str, int] = {}
    for t, p in zip(yte, pred):
        if t != p:
            confusions[f"{t} -> {p}"] = confusions.get(f"{t} -> {p}", 0) + 1
    return {
        "accuracy": float(np.mean(pred == yte)),
        "per_class_accuracy": per_class,
        "per_class_count": {c: int(np.sum(yte == c)) for c in classes},
        "n_train": len(ytr),
        "n_test": len(yte),
        "confusions": confusions,
        "k": 1,
        "features": {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(classifier.features).items()},
        "part_policy": PART_POLICY,
    }
