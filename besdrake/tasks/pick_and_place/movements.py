"""Label the segmenter's pieces of a recording with the 1-NN classifier, joining over-split movements.

vMCI sometimes splits one movement in two (a slow transport with a speed dip). Each piece then
looks like no whole training movement, and the 1-NN labels it with whatever lies nearest. Rule
(no threshold): two neighbouring pieces are joined when their union lies nearer to a training
movement (feature distance of the 1-NN) than either piece alone; the best such join first,
repeated until none is left. Pieces that cannot be classified (e.g. a marker missing) keep the
label None and are never joined.

Nothing in this rule is specific to the task; it could move to the segmentation stage.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from besdrake.segmentation.classification import ClassificationError, extract_segment


@dataclass
class LabelledSegments:
    """Row ranges ``(start, end)`` of the (joined) segments, their labels and 1-NN distances."""

    segments: list[tuple[int, int]]
    labels: list[str | None]
    distances: list[float]
    joined: int = 0
    problems: list[str] = field(default_factory=list)


def nearest(classifier, pre, start: int, end: int) -> tuple[str | None, float, str | None]:
    """Label and feature distance of the training movement nearest to rows ``start..end``
    (None, inf and the reason when the piece cannot be classified)."""
    try:
        X = classifier.features.transform([extract_segment(pre, start, end)])
    except ClassificationError as err:
        return None, float("inf"), str(err)
    dist = np.linalg.norm(classifier.X_train_ - X[0], axis=1)  # the 1-NN's Euclidean metric
    k = int(np.argmin(dist))
    return str(classifier.y_train_[k]), float(dist[k]), None


def label_segments(pre, segments: list[tuple[int, int]], classifier, join: bool = True) -> LabelledSegments:
    """1-NN labels of ``segments`` (row ranges of ``pre``), over-split movements joined (``join``)."""
    segs = [tuple(map(int, s)) for s in segments]
    found = [nearest(classifier, pre, a, b) for a, b in segs]
    problems = [f"segment {int(pre.frames[a])}..{int(pre.frames[b])} not classified: {why}"
                for (a, b), (_, _, why) in zip(segs, found) if why]
    labels, dists = [f[0] for f in found], [f[1] for f in found]
    joined, cache = 0, {}
    while join and len(segs) > 1:
        best = None
        for k in range(len(segs) - 1):
            if not (np.isfinite(dists[k]) and np.isfinite(dists[k + 1])):
                continue
            key = (segs[k][0], segs[k + 1][1])
            if key not in cache:
                cache[key] = nearest(classifier, pre, *key)
            label, d, _ = cache[key]
            gain = min(dists[k], dists[k + 1]) - d
            if gain > 0 and (best is None or gain > best[0]):
                best = (gain, k, label, d)
        if best is None:
            break
        _, k, label, d = best
        segs[k : k + 2] = [(segs[k][0], segs[k + 1][1])]
        labels[k : k + 2], dists[k : k + 2] = [label], [d]
        joined += 1
    return LabelledSegments(segs, labels, dists, joined, problems)
