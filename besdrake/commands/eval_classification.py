"""``besdrake eval classification --train DIR --test DIR``: 1-NN accuracy on manual segments."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from besdrake._io import write_text as _atomic_write_text

COMMAND = ("eval", "classification")
HELP = "train the 1-NN segment classifier on one folder of labelled recordings and score it on another"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--train", type=Path, required=True, help="folder of labelled recordings for training")
    parser.add_argument("--test", type=Path, required=True, help="folder of labelled recordings for testing")
    parser.add_argument("--json", action="store_true", help="print the metrics as one JSON object")
    parser.add_argument("--markers", nargs="+", default=None,
                        help="markers compared ('hand' = centroid of the hand markers); default: hand + object")
    parser.add_argument("--save-classifier", type=Path, default=None, help="write the trained classifier (JSON)")


def run(args: argparse.Namespace) -> int:
    from besdrake.cli import UserError
    from besdrake.segmentation.classification import SegmentClassifier
    from besdrake.segmentation.evaluation import evaluate_classifier, labelled_recordings

    try:
        train, test = labelled_recordings(args.train), labelled_recordings(args.test)
        clf = SegmentClassifier(markers=tuple(args.markers) if args.markers else "auto")
        report = evaluate_classifier(clf, train, test)
    except (OSError, ValueError) as err:
        raise UserError(str(err)) from None
    report = {"train": str(args.train), "test": str(args.test), **report}
    if args.save_classifier:
        _atomic_write_text(args.save_classifier, json.dumps(clf.to_json()))
    if args.json:
        print(json.dumps(report))
    else:
        print(f"accuracy {report['accuracy']:.3f} on {report['n_test']} segments")
        for c, a in report["per_class_accuracy"].items():
            print(f"  {c:24s} {a:.3f}")
    return 0
