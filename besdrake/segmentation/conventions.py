"""How a manual segmentation places its borders relative to the hand speed.

Border rules learned on one annotator transfer to another only as far as the two follow the
same conventions. :func:`annotation_conventions` measures them on labelled recordings, so a
user can see before tuning whether a labelled subject can teach the conventions of another
one's annotator:

* pauses: stretches inside the labelled range that no segment covers (longer than
  ``merge_s``); each has two borders under the scored border definition
  (:data:`~besdrake.segmentation.evaluation.BORDER_DEFINITION`);
* for every interior border: whether it is a pause edge, the hand speed there as a fraction of
  the highest speed within ``window_s`` around it, and the time from the nearest local
  minimum of the hand speed.

On the shared pick-and-place data the two annotators differ in both: one leaves a pause
between most movements and ends and starts movements at about a tenth of the peak speed, the
other labels the movements back to back and cuts at the speed minimum
(``scripts/bench_segmentation.py``, ``annotation_conventions``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from besdrake.mocap.segments_io import Segment
from besdrake.segmentation.evaluation import LabelledRecording, manual_borders

#: Seconds of hand speed on each side of a border whose maximum is its reference peak.
DEFAULT_WINDOW_S = 1.0


@dataclass(frozen=True)
class BorderContext:
    """One interior manual border and the hand speed around it."""

    frame: float  # the file's frame numbering
    pause_edge: bool  # the end or start of a pause (a stretch no labelled segment covers)
    speed: float  # m/s at the border
    speed_fraction: float  # speed / highest speed within window_s on either side
    from_minimum_s: float  # border time minus the time of the nearest local speed minimum


@dataclass(frozen=True)
class AnnotationConventions:
    """Summary of :class:`BorderContext` over recordings (quartiles are ``[q25, q50, q75]``)."""

    n_recordings: int
    n_borders: int
    n_pauses: int
    pause_edge_share: float  # share of the interior borders that are pause edges
    pause_s_median: float  # NaN without pauses
    speed_fraction_quartiles: list[float]
    pause_edge_speed_fraction_quartiles: list[float]  # NaN without pauses
    other_speed_fraction_quartiles: list[float]  # NaN when every border is a pause edge
    from_minimum_s_abs_quartiles: list[float]
    near_minimum_share: float  # borders within 0.1 s of a local speed minimum

    def to_dict(self) -> dict:
        return asdict(self)


def pauses(segments: list[Segment], frequency: float, merge_s: float = 0.1) -> list[tuple[int, int]]:
    """``(last covered frame, next covered frame)`` of each stretch no segment covers, longer than ``merge_s``."""
    spans = sorted((s.start_frame, s.end_frame) for s in segments)
    out = []
    if not spans:
        return out
    reach = spans[0][1]
    for start, end in spans[1:]:
        if start - reach > merge_s * frequency:
            out.append((reach, start))
        reach = max(reach, end)
    return out


def speed_minima(speed: np.ndarray) -> np.ndarray:
    """Indices of the interior local minima of ``speed`` (a sample no higher than either neighbour)."""
    i = np.arange(1, len(speed) - 1)
    return i[(speed[i] <= speed[i - 1]) & (speed[i] <= speed[i + 1])]


def border_contexts(segments: list[Segment], speed: np.ndarray, frequency: float, first_frame: int,
                    merge_s: float = 0.1, window_s: float = DEFAULT_WINDOW_S) -> list[BorderContext]:
    """The interior manual borders of one recording with the hand speed around them.

    ``speed``: ``(n,)`` hand speed (m/s) of the recording's frames ``first_frame ...``.
    """
    speed = np.asarray(speed, float)
    n = len(speed)
    if n < 3 or not np.all(np.isfinite(speed)):
        raise ValueError("border_contexts needs at least 3 finite hand speed samples")
    last_frame = first_frame + n - 1
    borders = manual_borders(segments, first_frame, last_frame, frequency, merge_s=merge_s)
    edges = [e for gap in pauses(segments, frequency, merge_s) for e in gap]
    minima = speed_minima(speed)
    w = max(1, int(round(window_s * frequency)))
    out = []
    for b in borders:
        k = int(np.clip(round(b - first_frame), 0, n - 1))
        peak = float(speed[max(0, k - w):k + w + 1].max())
        m = minima[np.argmin(np.abs(minima - k))] if len(minima) else k
        out.append(BorderContext(
            frame=float(b),
            pause_edge=bool(edges) and min(abs(b - e) for e in edges) <= merge_s * frequency,
            speed=float(speed[k]),
            speed_fraction=float(speed[k] / peak) if peak > 0 else 0.0,
            from_minimum_s=float((k - m) / frequency),
        ))
    return out


def _quartiles(x) -> list[float]:
    x = np.asarray(list(x), float)
    return [float(q) for q in np.percentile(x, [25, 50, 75])] if len(x) else [float("nan")] * 3


def annotation_conventions(recordings: list[LabelledRecording], preprocessed: dict | None = None,
                           merge_s: float = 0.1, window_s: float = DEFAULT_WINDOW_S) -> AnnotationConventions:
    """Measure the border conventions of the manual segmentations of ``recordings``.

    ``preprocessed`` may map ``str(path)`` to a preprocessed recording (as for
    :func:`~besdrake.segmentation.evaluation.evaluate_segmenter`); the hand speed is the norm of
    its ``hand_velocity``.
    """
    from besdrake.mocap.preprocess import preprocess

    if not recordings:
        raise ValueError("annotation_conventions needs at least one labelled recording")
    pre = preprocessed or {}
    contexts, n_pauses, pause_s = [], 0, []
    for rec in recordings:
        p = pre.get(str(rec.path)) or preprocess(rec.recording)
        speed = np.linalg.norm(p.hand_velocity, axis=1)
        contexts += border_contexts(rec.segments, speed, p.frequency, int(p.frames[0]), merge_s, window_s)
        gaps = pauses(rec.segments, p.frequency, merge_s)
        n_pauses += len(gaps)
        pause_s += [(b - a) / p.frequency for a, b in gaps]
    edge = [c for c in contexts if c.pause_edge]
    other = [c for c in contexts if not c.pause_edge]
    n = len(contexts)
    return AnnotationConventions(
        n_recordings=len(recordings),
        n_borders=n,
        n_pauses=n_pauses,
        pause_edge_share=len(edge) / n if n else float("nan"),
        pause_s_median=float(np.median(pause_s)) if pause_s else float("nan"),
        speed_fraction_quartiles=_quartiles(c.speed_fraction for c in contexts),
        pause_edge_speed_fraction_quartiles=_quartiles(c.speed_fraction for c in edge),
        other_speed_fraction_quartiles=_quartiles(c.speed_fraction for c in other),
        from_minimum_s_abs_quartiles=_quartiles(abs(c.from_minimum_s) for c in contexts),
        near_minimum_share=float(np.mean([abs(c.from_minimum_s) <= 0.1 for c in contexts])) if n else float("nan"),
    )
