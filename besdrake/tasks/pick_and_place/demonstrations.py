"""Grasp demonstrations from real pick-and-place recordings, without a person.

:func:`extract_demonstrations` takes one Qualisys TSV (or C3D) recording with named markers
(or unnamed trajectories and a fitted :class:`~besdrake.mocap.labeling.MarkerLabeler`, which
names them first) through the project's stages:

1. preprocessing (:func:`besdrake.mocap.preprocess.preprocess`: gap filling, hand pose);
2. vMCI segmentation (:class:`besdrake.segmentation.VMCI`, default priors and rules);
3. 1-NN classification of every segment (the shipped classifier,
   :func:`~besdrake.tasks.pick_and_place.classifier.load_classifier`), over-split movements
   joined (:mod:`~besdrake.tasks.pick_and_place.movements`);
4. pairing: a run of ``approach_forward`` segments followed, with only ``idle`` segments
   between, by a run of ``move_obj_table`` segments is one grasp and transport;
5. per pair: the grasp's events (:mod:`~besdrake.tasks.pick_and_place.grasp_events`), the box's
   places, the task frame (:mod:`~besdrake.tasks.pick_and_place.task_frame`) and the hand pose,
   grip aperture and box path in it: a :class:`GraspDemonstration`.

Nothing here reads a manual segmentation. A recording that lacks the box or finger markers, or in
which no pair is found, gives per-file problems; a pair that cannot be used gives a
:class:`RejectedPair` with the reason. Only a caller's own error (e.g. a missing classifier file)
raises.

Grip aperture: the distance between the ``Thumb`` and ``Index`` markers (fingertips); where
``Index`` is missing, the ``Thumb``-``Middle`` distance shifted by the recording's median
difference between the two.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from besdrake.mocap.preprocess import (
    BACK_MARKERS, HAND_MARKERS, PreprocessError, back_frame, preprocess, rotation_to_quaternion,
)
from besdrake.mocap.qualisys import read_recording
from besdrake.mocap.recording import MocapRecording
from besdrake.segmentation import VMCI, SegmentationError
from besdrake.tasks.pick_and_place.grasp_events import GraspEventError, grasp_events
from besdrake.tasks.pick_and_place.movements import label_segments
from besdrake.tasks.pick_and_place.task_frame import TaskFrame, TaskFrameError, horizontal_yaw, task_frame

BOX_MARKERS = ("Box back", "Box left")
FINGER_MARKERS = ("Thumb", "Index", "Middle")
APPROACH, TRANSPORT, PAUSE = "approach_forward", "move_obj_table", "idle"
#: The carry is searched up to this long (s) after the transport segment's end (the segmenter's
#: border may come early).
CARRY_MARGIN_S = 0.5
#: The box's rest place on the table is the median over this long (s) after the place.
PLACE_WINDOW_S = 0.5


@dataclass
class GraspDemonstration:
    """One ``approach_forward`` + ``move_obj_table`` pair in the task frame (SI units).

    Arrays cover rows ``frames`` of the recording: from the approach's start to the later of the
    transport's end and the grip's opening. ``t`` starts at 0. Orientation: unit quaternions
    ``(w, x, y, z)`` of the hand plate frame in the task frame (built from ``Hand top``, ``Hand
    right``, ``Hand left`` as :func:`besdrake.mocap.preprocess.back_frame` builds the back frame:
    y from right to left, z towards top, x = y x z). ``box_position``: the box's path (midpoint
    of its markers). ``border_index``: the row where the transport segment starts (a pause
    between approach and transport belongs to the approach). Events (s of ``t``): ``close``
    (the fingers close on the box), ``lift`` (the box starts moving), ``place`` (it stops on the
    table), ``open`` (the fingers open; see :mod:`~besdrake.tasks.pick_and_place.grasp_events`).
    Box places: midpoint of the box markers in the task frame, yaw (rad, about task z) of
    the line through ``Box back`` and ``Box left`` modulo a half turn, in [-pi/2, pi/2) (a box is
    the same after a half turn, and the automatic labeller cannot always tell the two box markers
    apart: both figures are the same when they are swapped). ``box_marker_span``: distance
    between the two box markers (m, a lower bound of the box's extent); ``hold_aperture``: median grip aperture while
    carried (m; the box's width across the grip plus the fingertip markers' offsets).
    """

    source: str
    approach_frames: tuple[int, int]
    transport_frames: tuple[int, int]
    frames: np.ndarray
    t: np.ndarray
    hand_position: np.ndarray
    hand_orientation: np.ndarray
    aperture: np.ndarray
    box_position: np.ndarray
    border_index: int
    close_time: float
    lift_time: float
    place_time: float
    open_time: float
    shelf_box_position: np.ndarray
    shelf_box_yaw: float
    table_box_position: np.ndarray
    table_box_yaw: float
    box_marker_span: float
    hold_aperture: float
    frame_origin: np.ndarray
    frame_rotation: np.ndarray
    closing_axis_hand: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    notes: list[str] = field(default_factory=list)

    _SCALARS = ("border_index", "close_time", "lift_time", "place_time", "open_time", "shelf_box_yaw",
                "table_box_yaw", "box_marker_span", "hold_aperture")
    _ARRAYS = ("frames", "t", "hand_position", "hand_orientation", "aperture", "box_position",
               "shelf_box_position", "table_box_position", "frame_origin", "frame_rotation", "closing_axis_hand")

    @property
    def task_frame(self) -> TaskFrame:
        return TaskFrame(self.frame_origin, self.frame_rotation)

    def summary(self) -> dict:
        """Scalars and places as JSON-ready values."""
        out = {"source": self.source, "approach_frames": list(self.approach_frames),
               "transport_frames": list(self.transport_frames), "samples": int(len(self.t)),
               "duration_s": float(self.t[-1])}
        out.update({k: float(getattr(self, k)) for k in self._SCALARS})
        out["border_index"] = int(self.border_index)
        out["shelf_box_position"] = [float(v) for v in self.shelf_box_position]
        out["table_box_position"] = [float(v) for v in self.table_box_position]
        out["notes"] = list(self.notes)
        return out

    def to_npz(self, path: str | Path) -> Path:
        """Write as ``.npz`` (arrays, scalars; source, frame ranges and notes as JSON text)."""
        meta = {"format": "besdrake.pnp_grasp_demonstration/1", "source": self.source,
                "approach_frames": list(self.approach_frames), "transport_frames": list(self.transport_frames),
                "notes": list(self.notes)}
        np.savez_compressed(path, meta=np.array(json.dumps(meta)),
                            **{k: np.asarray(getattr(self, k)) for k in self._ARRAYS + self._SCALARS})
        return Path(path)

    @classmethod
    def from_npz(cls, path: str | Path) -> "GraspDemonstration":
        with np.load(path, allow_pickle=False) as npz:
            meta = json.loads(str(npz["meta"]))
            if meta.get("format") != "besdrake.pnp_grasp_demonstration/1":
                raise ValueError(f"{path}: not a besdrake grasp demonstration")
            arrays = {k: npz[k].copy() for k in cls._ARRAYS if k in npz}  # closing_axis_hand: newer files
            scalars = {k: npz[k].item() for k in cls._SCALARS}
        return cls(source=meta["source"], approach_frames=tuple(meta["approach_frames"]),
                   transport_frames=tuple(meta["transport_frames"]), notes=list(meta["notes"]),
                   **arrays, **scalars)


@dataclass
class RejectedPair:
    """An approach/transport pair the classifier found but that gives no usable demonstration."""

    approach_frames: tuple[int, int]
    transport_frames: tuple[int, int]
    reason: str

    def to_dict(self) -> dict:
        return {"approach_frames": list(self.approach_frames), "transport_frames": list(self.transport_frames),
                "reason": self.reason}


@dataclass
class DemonstrationResult:
    """What one recording gave: demonstrations, rejected pairs, file-level problems, the labelled segments."""

    source: str
    demonstrations: list[GraspDemonstration] = field(default_factory=list)
    rejected: list[RejectedPair] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    segments: list[dict] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def pairs_found(self) -> int:
        return len(self.demonstrations) + len(self.rejected)

    def to_dict(self) -> dict:
        return {"file": self.source, "pairs_found": self.pairs_found, "demonstrations": [d.summary() for d in self.demonstrations],
                "rejected": [r.to_dict() for r in self.rejected], "problems": list(self.problems),
                "segments": list(self.segments), "seconds": round(self.seconds, 3)}


def missing_markers(rec: MocapRecording) -> list[str]:
    """The markers this task needs that the recording lacks or never sees, each with why."""
    absent = set(rec.marker_names) - set(rec.missing_markers())
    out = []
    for name in (*HAND_MARKERS, *BACK_MARKERS, *BOX_MARKERS, "Thumb"):
        if name not in absent:
            out.append(f"{name!r} ({'never visible' if name in rec.marker_names else 'not in the file'})")
    if "Index" not in absent and "Middle" not in absent:
        out.append("'Index' and 'Middle' (neither is in the file or visible)")
    return out


def grip_aperture(positions: np.ndarray, marker_names: list[str]) -> np.ndarray:
    """``(n,)`` Thumb-Index distance (m), Thumb-Middle shifted by their median difference where Index is missing."""
    def dist(a: str, b: str) -> np.ndarray:
        if a not in marker_names or b not in marker_names:
            return np.full(len(positions), np.nan)
        return np.linalg.norm(positions[:, marker_names.index(a)] - positions[:, marker_names.index(b)], axis=1)

    ti, tm = dist("Thumb", "Index"), dist("Thumb", "Middle")
    both = np.isfinite(ti) & np.isfinite(tm)
    offset = float(np.median(ti[both] - tm[both])) if both.any() else 0.0
    return np.where(np.isfinite(ti), ti, tm + offset)


def find_pairs(labels: list[str | None], segments: list[tuple[int, int]]) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """Row ranges ``((a0, a1), (t0, t1))`` of every approach run followed by a transport run
    (consecutive segments of one label form a run; only ``idle`` segments may lie between)."""
    runs: list[list] = []
    for label, (a, b) in zip(labels, segments):
        if runs and runs[-1][0] == label:
            runs[-1][2] = b
        else:
            runs.append([label, a, b])
    pairs = []
    for i, (label, a, b) in enumerate(runs):
        if label != APPROACH:
            continue
        j = i + 1
        while j < len(runs) and runs[j][0] == PAUSE:
            j += 1
        if j < len(runs) and runs[j][0] == TRANSPORT:
            pairs.append(((a, b), (runs[j][1], runs[j][2])))
    return pairs


def extract_demonstrations(path: str | Path, classifier=None, segmenter=None, join: bool = True,
                           labeler=None) -> DemonstrationResult:
    """Grasp demonstrations of one recording (see the module docstring).

    ``classifier``: a fitted :class:`~besdrake.segmentation.SegmentClassifier` (default: the
    shipped one); ``segmenter``: a vMCI-like segmenter (default ``VMCI()``); ``join``: join
    over-split movements (:func:`~besdrake.tasks.pick_and_place.movements.label_segments`);
    ``labeler``: a fitted :class:`~besdrake.mocap.labeling.MarkerLabeler` that names the
    recording's trajectories first (for recordings of unnamed trajectories)."""
    from besdrake.tasks.pick_and_place.classifier import load_classifier

    t_start = time.process_time()
    result = DemonstrationResult(source=str(path))
    classifier = classifier if classifier is not None else load_classifier()
    try:
        rec = read_recording(path)
        if labeler is not None:
            rec = labeler.predict(rec).recording
    except (OSError, ValueError) as err:  # MocapFormatError and LabelingError are ValueErrors
        result.problems.append(f"cannot read or label the recording: {err}")
        return result
    absent = missing_markers(rec)
    if absent:
        result.problems.append("missing markers: " + ", ".join(absent))
        return result
    try:
        pre = preprocess(rec)
        seg = (segmenter if segmenter is not None else VMCI()).fit(pre)
    except (PreprocessError, SegmentationError) as err:
        result.problems.append(f"cannot segment the recording: {err}")
        return result
    lab = label_segments(pre, seg.segments_, classifier, join=join)
    result.problems.extend(lab.problems)
    result.segments = [{"start_frame": int(pre.frames[a]), "end_frame": int(pre.frames[b]), "label": l}
                       for (a, b), l in zip(lab.segments, lab.labels)]
    pairs = find_pairs(lab.labels, lab.segments)
    if not pairs:
        found = sorted({l for l in lab.labels if l})
        result.problems.append(f"no {APPROACH} followed by {TRANSPORT} among the classified movements (found: {', '.join(found) or 'none'})")
    for approach, transport in pairs:
        try:
            result.demonstrations.append(_demonstration(str(path), pre, approach, transport))
        except (GraspEventError, TaskFrameError, _Unusable) as err:
            frames = lambda r: (int(pre.frames[r[0]]), int(pre.frames[r[1]]))  # noqa: E731
            result.rejected.append(RejectedPair(frames(approach), frames(transport), str(err)))
    result.seconds = time.process_time() - t_start
    return result


class _Unusable(ValueError):
    """A pair whose data cannot make a demonstration (gaps, inconsistent events)."""


def _demonstration(source: str, pre, approach: tuple[int, int], transport: tuple[int, int]) -> GraspDemonstration:
    names, f = pre.marker_names, pre.frequency
    box_markers = np.stack([pre.positions[:, names.index(n)] for n in BOX_MARKERS], axis=1)
    box = box_markers.mean(axis=1)
    aperture = grip_aperture(pre.positions, names)
    signals = {"box": box, "grip aperture": aperture, "hand": pre.hand_position}
    _require_finite(pre, np.arange(approach[0], transport[1] + 1), signals)
    carry_stop = min(pre.n_frames - 1, transport[1] + int(round(CARRY_MARGIN_S * f)))
    ev = grasp_events(aperture, box, pre.hand_position, f, approach[0], carry_stop)
    if ev.place < transport[0] or ev.lift > transport[1]:
        raise _Unusable(f"the box is carried in frames {int(pre.frames[ev.lift])}..{int(pre.frames[ev.place])}, "
                        "not during the transport segment")
    a = approach[0]
    rows = np.arange(a, max(transport[1], ev.open) + 1)
    _require_finite(pre, rows, signals)
    rest = slice(ev.place, min(pre.n_frames, ev.place + int(round(PLACE_WINDOW_S * f)) + 1))
    before = slice(a, ev.lift + 1)
    frame = task_frame(np.median(box[before], axis=0), np.median(box[rest], axis=0))
    axis = box_markers[:, 1] - box_markers[:, 0]
    hand_rot = back_frame(*(pre.positions[rows, names.index(n)] for n in HAND_MARKERS))[1]
    closing = closing_axis(pre, hand_rot[ev.lift - a : ev.place - a + 1], np.arange(ev.lift, ev.place + 1))
    t0 = pre.time[a]
    notes = list(ev.notes)
    if ev.open > transport[1]:
        notes.append(f"the grip opens {(ev.open - transport[1]) / f:.2f} s after the transport segment ends")
    return GraspDemonstration(
        source=source, approach_frames=(int(pre.frames[approach[0]]), int(pre.frames[approach[1]])),
        transport_frames=(int(pre.frames[transport[0]]), int(pre.frames[transport[1]])),
        frames=pre.frames[rows].copy(), t=pre.time[rows] - t0,
        hand_position=frame.points(pre.hand_position[rows]),
        hand_orientation=rotation_to_quaternion(frame.rotations(hand_rot)),
        aperture=aperture[rows].copy(), box_position=frame.points(box[rows]),
        border_index=int(transport[0] - a),
        close_time=float(pre.time[ev.close] - t0), lift_time=float(pre.time[ev.lift] - t0),
        place_time=float(pre.time[ev.place] - t0), open_time=float(pre.time[ev.open] - t0),
        shelf_box_position=frame.points(np.median(box[before], axis=0)), shelf_box_yaw=_yaw(frame, axis[before]),
        table_box_position=frame.points(np.median(box[rest], axis=0)), table_box_yaw=_yaw(frame, axis[rest]),
        box_marker_span=float(np.median(np.linalg.norm(axis[ev.lift : ev.place + 1], axis=1))),
        hold_aperture=ev.hold_aperture, frame_origin=frame.origin, frame_rotation=frame.rotation,
        closing_axis_hand=closing, notes=notes,
    )


def closing_axis(pre, hand_rot: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """The grip's closing line in the hand plate frame (unit, from the ``Thumb`` towards the midpoint of ``Index``
    and ``Middle``): the median over the carried frames ``rows`` where the three fingertip markers are seen
    (``hand_rot`` (len(rows), 3, 3): the hand plate's rotation in the capture frame); NaN when none is."""
    names = pre.marker_names
    thumb = pre.positions[rows, names.index("Thumb")]
    fingers = 0.5 * (pre.positions[rows, names.index("Index")] + pre.positions[rows, names.index("Middle")])
    v = np.einsum("nji,nj->ni", hand_rot, fingers - thumb)
    v = v[np.isfinite(v).all(axis=1)]
    if len(v) == 0:
        return np.full(3, np.nan)
    m = np.median(v / np.linalg.norm(v, axis=1, keepdims=True), axis=0)
    return m / np.linalg.norm(m)


def _yaw(frame: TaskFrame, world_axis: np.ndarray) -> float:
    """Yaw of the box-marker axis in the task frame, modulo a half turn, in [-pi/2, pi/2)."""
    yaw = float(horizontal_yaw(frame.directions(np.median(world_axis, axis=0))))
    return float((yaw + np.pi / 2) % np.pi - np.pi / 2)


def _require_finite(pre, rows: np.ndarray, signals: dict[str, np.ndarray]) -> None:
    for name, x in signals.items():
        bad = ~np.isfinite(x[rows]).reshape(len(rows), -1).all(axis=1)
        if bad.any():
            frames = pre.frames[rows][bad]
            raise _Unusable(f"{name} is missing at {int(bad.sum())} frames ({int(frames[0])}..{int(frames[-1])}) "
                            "in gaps too long to fill")


__all__ = ["BOX_MARKERS", "FINGER_MARKERS", "DemonstrationResult", "GraspDemonstration", "RejectedPair",
           "extract_demonstrations", "find_pairs", "grip_aperture", "missing_markers"]
