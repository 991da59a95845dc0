"""Retrain the shipped pick-and-place movement classifier.

    python -m besdrake.tasks.pick_and_place.train_classifier --data DIR --out FILE [--subjects subject1 subject2]

``DIR`` holds ``*.tsv`` recordings with ``*_manually_segmented.json`` beside them. ``--out``
defaults to the packaged ``classifier.npz`` (the shipped one is trained on all recordings of
subjects 1 and 2 of ``../shared/data/pick_and_place``). Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from besdrake.tasks.pick_and_place.classifier import CLASSIFIER_PATH, save_classifier, train_classifier


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m besdrake.tasks.pick_and_place.train_classifier",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, help="folder of labelled recordings")
    ap.add_argument("--out", type=Path, default=CLASSIFIER_PATH, help=f"output .npz (default {CLASSIFIER_PATH})")
    ap.add_argument("--subjects", nargs="*", default=None, help="file-name prefixes to train on (default: all)")
    args = ap.parse_args(argv)
    if args.out.suffix != ".npz":
        print(f"besdrake: error: --out {args.out}: the classifier is written as .npz", file=sys.stderr)
        return 2
    try:
        clf, info = train_classifier(args.data, args.subjects)
    except (OSError, ValueError) as err:
        print(f"besdrake: error: {err}", file=sys.stderr)
        return 2
    info["markers"] = list(clf.markers_)
    path = save_classifier(clf, args.out, info)
    print(json.dumps({"out": str(path), "bytes": path.stat().st_size, **info}))
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
