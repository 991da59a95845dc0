"""From a demonstration to the robot's motion plans: the stages up to imitation, chained.

``recording -> gap filling -> preprocessing -> throw segments (vMCI + 1-NN, or a given
segmentation) -> embodiment mapping (sync frame, IK, scaling, DMP) -> nominal simulation``.

Each throw is processed on its own: a throw that cannot be imitated (too short, NaN samples,
unreachable) is reported with its error and the others go on.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from besdrake.mocap.gaps import fill_gaps
from besdrake.mocap.preprocess import BACK_MARKERS, HAND_MARKERS, Preprocessed, preprocess
from besdrake.mocap.recording import MocapRecording
from besdrake.mocap.segments_io import Segment

#: The class of segments that are imitated.
THROW_LABEL = "throw"
#: Synthetic subjects whose first experiment trains the default classifier (the paper: 40 throws
#: of subjects 1-5, one experiment each).
DEFAULT_TRAINING_SUBJECTS = (0, 1, 2, 3, 4)
#: Gaps up to this long are filled before preprocessing (s); plate markers by a rigid fit to their
#: two visible partners, which holds over long gaps (the plate is rigid).
MAX_GAP_S = 1.0


@dataclass
class ThrowReport:
    """What happened to one throw segment."""

    index: int
    start_frame: int
    end_frame: int
    ok: bool
    error: str | None = None
    summary: dict[str, Any] = field(default_factory=dict)
    landing: dict[str, Any] | None = None


def load_demonstration(source: str) -> list[tuple[str, MocapRecording, list[Segment] | None]]:
    """Recordings named by ``source``: a TSV/C3D path, or ``synthetic:S`` / ``synthetic:S:E``
    (subject S, experiment E of the built-in synthetic demonstrator, seed 0). Synthetic
    recordings come with their ground-truth segmentation (used only when asked for)."""
    if source.startswith("synthetic:"):
        from besdrake.tasks.throwing.demonstrator import SyntheticDemonstrator

        parts = source.split(":")[1:]
        try:
            subject = int(parts[0])
            experiments = [int(parts[1])] if len(parts) > 1 else [0, 1, 2]
        except (ValueError, IndexError):
            raise ValueError(f"synthetic source must look like synthetic:SUBJECT[:EXPERIMENT], got {source!r}") from None
        demo = SyntheticDemonstrator(0).subject(subject)
        out = []
        for e in experiments:
            exp = demo.experiment(e)
            out.append((f"synthetic_s{subject}_e{e}", exp.recording, exp.segments))
        return out
    from besdrake.mocap.qualisys import read_recording
    from besdrake.mocap.segments_io import read_segmentation, segmentation_path

    path = Path(source)
    if not path.is_file():
        raise FileNotFoundError(f"{source}: no such recording")
    seg_path = segmentation_path(path)
    segments = read_segmentation(seg_path) if seg_path.is_file() else None
    return [(path.stem, read_recording(path), segments)]


def prepare(rec: MocapRecording) -> Preprocessed:
    """Fill plate-marker gaps (rigid fit), crop away a start or end where a hand or back marker is
    still missing (edge gaps cannot be interpolated), and preprocess."""
    plates = [list(BACK_MARKERS), list(HAND_MARKERS)]
    plates = [p for p in plates if all(m in rec.marker_names for m in p)]
    filled = fill_gaps(rec, max_gap_s=MAX_GAP_S, plates=plates).recording
    needed = [filled.marker_index(m) for m in (*BACK_MARKERS, *HAND_MARKERS) if m in filled.marker_names]
    complete = filled.visible()[:, needed].all(axis=1)
    if complete.any() and not (complete[0] and complete[-1]):
        rows = np.flatnonzero(complete)
        filled = filled.crop(int(filled.frames[rows[0]]), int(filled.frames[rows[-1]]))
    return preprocess(filled, max_gap_s=MAX_GAP_S)


def default_classifier():
    """1-NN classifier trained on the first experiment of synthetic subjects 0-4 (40 throws)."""
    from besdrake.tasks.throwing.demonstrator import SyntheticDemonstrator
    from besdrake.segmentation.classification import SegmentClassifier, extract_segment
    from besdrake.segmentation.evaluation import pre_index

    demo = SyntheticDemonstrator(0)
    segments, labels = [], []
    for s in DEFAULT_TRAINING_SUBJECTS:
        exp = demo.subject(s).experiment(0)
        pre = prepare(exp.recording)
        for seg in exp.segments:
            a, b = pre_index(pre.frames, seg.start_frame), pre_index(pre.frames, seg.end_frame)
            segments.append(extract_segment(pre, a, b, seg.label))
            labels.append(seg.label)
    return SegmentClassifier(markers=("hand",)).fit(segments, labels)


def find_throws(pre: Preprocessed, classifier=None, segments: list[Segment] | None = None) -> list[tuple[int, int]]:
    """Frame ranges of the throw segments: from ``segments`` when given, else vMCI + 1-NN."""
    if segments is not None:
        return [(s.start_frame, s.end_frame) for s in segments if s.label == THROW_LABEL]
    from besdrake.segmentation import VMCI
    from besdrake.segmentation.classification import extract_segment

    seg = VMCI().fit(pre)
    classifier = classifier or default_classifier()
    throws = []
    for a, b in seg.segments_:
        if classifier.predict([extract_segment(pre, a, b)])[0] == THROW_LABEL:
            throws.append((int(pre.frames[a]), int(pre.frames[b])))
    return throws


def imitate_recording(
    name: str,
    pre: Preprocessed,
    throws: list[tuple[int, int]],
    out_dir: Path | None = None,
    simulate: bool = True,
    scenario: str = "nominal",
    figures: bool = True,
    mapping=None,
    rollout=None,
) -> list[ThrowReport]:
    """Imitate every throw of one recording; write plans, summaries and figures to ``out_dir``."""
    from besdrake.embodiment import EmbodimentMapping
    from besdrake.sim.scenario import load_scenario

    mapping = mapping or EmbodimentMapping(load_scenario(scenario).robot)
    if simulate and rollout is None:
        from besdrake.sim import Rollout

        rollout = Rollout(scenario)
    return [imitate_throw(f"{name}_throw{i}", i, pre, f0, f1, mapping, rollout if simulate else None, out_dir, figures)
            for i, (f0, f1) in enumerate(throws)]


def imitate_throw(throw_name: str, i: int, pre: Preprocessed, f0: int, f1: int, mapping, rollout=None,
                  out_dir: Path | None = None, figure: bool = True) -> ThrowReport:
    """Imitate throw ``i`` (frames ``f0..f1`` of ``pre``) with ``mapping``; simulate it with ``rollout`` (None: not
    simulated); write its plan, summary and (``figure``) figure to ``out_dir``. An error is reported, not raised."""
    from besdrake.embodiment import hand_trajectory

    try:
        hand = hand_trajectory(pre, f0, f1)
        result = mapping.imitate(hand, name=throw_name)
    except Exception as err:  # one bad throw must not stop the others
        return ThrowReport(i, f0, f1, ok=False, error=f"{type(err).__name__}: {err}")
    report = ThrowReport(i, f0, f1, ok=result.executable, summary=result.summary())
    if rollout is not None:
        t0 = time.perf_counter()
        outcome = rollout.rollout(result.plan, limits="flag")
        report.landing = outcome.summary() | {"sim_time_s": time.perf_counter() - t0}
    if out_dir is not None:
        result.save(out_dir)
        if figure:
            from besdrake.embodiment.figures import plot_imitation

            plot_imitation(result, hand, mapping.welded, out_dir / f"{throw_name}.png")
    return report


def reports_to_json(reports: list[ThrowReport]) -> list[dict[str, Any]]:
    return [
        {
            "index": r.index,
            "start_frame": r.start_frame,
            "end_frame": r.end_frame,
            "executable": r.ok,
            "error": r.error,
            **r.summary,
            "simulation": r.landing,
        }
        for r in reports
    ]
