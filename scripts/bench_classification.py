#!/usr/bin/env python3
"""Benchmark: 1-NN movement classification of manual segments.

Prints one JSON object:

* ``pick_and_place``: trained on one subject, tested on the other (both directions), with the
  default features (hand + box in the back frame, normalised speed profile) and, measured in
  the same run, the hand path alone (the quoted baseline's features); the quoted figures of
  the baseline and the paper are constants.
* ``synthetic_throws`` (``--synthetic DIR`` or ``--generate``): train on subjects 1-5, test on
  6-10: accuracy, per class; plus the end-to-end figure: vMCI segments of the test
  recordings labelled by the classifier, fraction of demonstrated throws found by the
  segmenter (start and end within 0.2 s) and, of those, labelled ``throw``.

Usage: python3 scripts/bench_classification.py [--data DIR] [--synthetic DIR | --generate]
"""

from __future__ import annotations

import argparse
import itertools
import json
import tempfile
from pathlib import Path

import numpy as np

from besdrake.mocap.preprocess import preprocess
from besdrake.segmentation import VMCI
from besdrake.segmentation.classification import SegmentClassifier, extract_segment
from besdrake.segmentation.evaluation import evaluate_classifier, labelled_recordings, matching_segments

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "pick_and_place"
QUOTED = {
    "hand_path_baseline": {"one_way": 0.97, "other_way": 0.85,
                           "note": "quoted: 1-NN on the time-normalised hand path in the back frame"},
    "paper_throws": {"same_subjects": 0.932, "new_subjects": 0.891, "throw_same": 0.986, "throw_new": 0.939},
}
TARGETS = {"pick_and_place_accuracy": 0.95, "throws_accuracy": 0.95, "throw_class": 0.99}


def short(r: dict) -> dict:
    return {k: r[k] for k in ("accuracy", "per_class_accuracy", "per_class_count", "n_train", "n_test", "confusions")}


def pick_and_place(directory: Path) -> dict:
    recs = labelled_recordings(directory)
    subjects = sorted({r.path.name.split("_")[0] for r in recs})
    by = {s: [r for r in recs if r.path.name.startswith(s + "_")] for s in subjects}
    out = {}
    for a, b in itertools.permutations(subjects, 2):
        ours = evaluate_classifier(SegmentClassifier(), by[a], by[b])
        hand = evaluate_classifier(
            SegmentClassifier(markers=("hand",), velocity_weight=0.0, path_length_weight=0.0), by[a], by[b]
        )
        out[f"train_{a}_test_{b}"] = {
            "default": short(ours),
            "hand_path_only_measured": short(hand),
            "features": ours["features"],
        }
    out["part_policy"] = ours["part_policy"]
    out["quoted"] = QUOTED["hand_path_baseline"]
    return out


def synthetic(directory: Path) -> dict:
    recs = labelled_recordings(directory)
    subj = lambda r: int(r.path.name.split("_")[0].replace("subject", ""))  # noqa: E731
    train = [r for r in recs if subj(r) <= 5]
    test = [r for r in recs if subj(r) > 5]
    clf = SegmentClassifier()
    res = evaluate_classifier(clf, train, test)
    # end to end: vMCI segments labelled by the classifier
    found = labelled_throw = total = 0
    seg = VMCI()
    for rec in test:
        pre = preprocess(rec.recording)
        seg.fit(pre)
        frames = pre.frames[np.array(seg.segments_)]
        for _, i in matching_segments(frames, rec.segments, pre.frequency, 0.2, label="throw"):
            total += 1
            if i is not None:
                found += 1
                a, b = seg.segments_[i]
                labelled_throw += clf.predict([extract_segment(pre, a, b)])[0] == "throw"
    return {
        "manual_segments": short(res),
        "features": res["features"],
        "end_to_end": {"throws": total, "found_by_vmci": found, "found_fraction": found / max(total, 1),
                       "found_and_labelled_throw": int(labelled_throw)},
        "quoted_paper": QUOTED["paper_throws"],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--synthetic", type=Path, default=None)
    ap.add_argument("--generate", action="store_true")
    args = ap.parse_args()
    report = {"targets": TARGETS, "pick_and_place": pick_and_place(args.data)}
    if args.synthetic:
        report["synthetic_throws"] = synthetic(args.synthetic)
    elif args.generate:
        from besdrake.tasks.throwing.demonstrator import generate_dataset

        with tempfile.TemporaryDirectory() as tmp:
            generate_dataset(tmp, n_subjects=10, n_experiments=3, n_throws=8, seed=0, unlabeled=False)
            report["synthetic_throws"] = synthetic(Path(tmp))
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
