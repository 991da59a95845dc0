"""The shipped pick-and-place movement classifier: a 1-NN over the segmentation stage's features.

``classifier.npz`` (beside this module, package data) holds a
:class:`~besdrake.segmentation.classification.SegmentClassifier` fitted on the manual segments of
all shared recordings of subjects 1 and 2 (``../shared/data/pick_and_place``): its parameters as
JSON text, the training feature rows ``X`` and their labels ``y``. No pickle: it is read with
``allow_pickle=False``. Retrain it with

    python -m besdrake.tasks.pick_and_place.train_classifier --data DIR --out FILE
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from besdrake.segmentation.classification import ClassificationError, SegmentClassifier

#: The classifier shipped with the package.
CLASSIFIER_PATH = Path(__file__).with_name("classifier.npz")
#: The annotators' movement classes of the pick-and-place recordings (plus ``idle`` pauses).
CLASSES = ("approach_forward", "move_obj_table", "move_to_rest_right", "approach_right",
           "move_obj_shelf", "move_to_rest_down")


def train_classifier(directory: str | Path, subjects: list[str] | None = None) -> tuple[SegmentClassifier, dict]:
    """Fit the default 1-NN on the manual segments of the labelled recordings in ``directory``.

    ``subjects``: file-name prefixes to keep (e.g. ``["subject1"]``); None keeps all.
    Returns the classifier and a summary (files, segments per class)."""
    from besdrake.segmentation.evaluation import labelled_recordings, labelled_segments

    recs = labelled_recordings(directory)
    if subjects:
        recs = [r for r in recs if any(r.path.name.startswith(s + "_") for s in subjects)]
        if not recs:
            raise FileNotFoundError(f"{directory} holds no labelled recording of {subjects}")
    segments, labels = labelled_segments(recs)
    clf = SegmentClassifier().fit(segments, labels)
    counts = {str(c): int(np.sum(clf.y_train_ == c)) for c in clf.classes_}
    return clf, {"files": [r.path.name for r in recs], "segments": len(labels), "per_class": counts}


def save_classifier(clf: SegmentClassifier, path: str | Path, info: dict | None = None) -> Path:
    """Write a fitted classifier as ``.npz`` (params JSON text, ``X`` float32, ``y`` unicode)."""
    data = clf.to_json()
    meta = {"format": data["format"], "params": data["params"], "info": info or {}}
    path = Path(path)
    np.savez_compressed(path, meta=np.array(json.dumps(meta)), X=np.asarray(data["X"], dtype=np.float32),
                        y=np.array(data["y"], dtype=str))
    return path


def load_classifier(path: str | Path | None = None) -> SegmentClassifier:
    """The classifier in ``path`` (default: the shipped :data:`CLASSIFIER_PATH`)."""
    path = Path(path) if path is not None else CLASSIFIER_PATH
    try:
        with np.load(path, allow_pickle=False) as npz:
            meta = json.loads(str(npz["meta"]))
            X, y = npz["X"].astype(float), npz["y"]
    except (OSError, KeyError, ValueError) as err:
        raise ClassificationError(f"{path}: not a besdrake classifier .npz ({err})") from None
    return SegmentClassifier.from_json({"format": meta.get("format"), "params": meta.get("params", {}),
                                        "X": X, "y": y})


def classifier_info(path: str | Path | None = None) -> dict:
    """The training summary stored with a classifier file (files, segments per class)."""
    with np.load(Path(path) if path is not None else CLASSIFIER_PATH, allow_pickle=False) as npz:
        return json.loads(str(npz["meta"])).get("info", {})
