"""``besdrake segment FILE``: vMCI segmentation of one recording (optionally labelled by a 1-NN classifier)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

COMMAND = ("segment",)
HELP = "segment a recording (Qualisys TSV or C3D) into movement building blocks with vMCI"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="recording (.tsv Qualisys export or .c3d)")
    parser.add_argument("--json", action="store_true", help="print the segments as one JSON object")
    parser.add_argument("--method", choices=("vmci", "zvc"), default="vmci",
                        help="vmci (default) or the zero-velocity-crossing baseline")
    parser.add_argument("--classifier", type=Path, default=None,
                        help="classifier JSON written by 'besdrake eval classification --save-classifier'")
    parser.add_argument("--train", type=Path, default=None,
                        help="folder of labelled recordings to train a 1-NN classifier on (instead of --classifier)")
    parser.add_argument("--segmenter", type=Path, default=None, metavar="FILE",
                        help="tuned vMCI (priors and border rules) written by 'besdrake eval segmentation --tune-on DIR --save-segmenter FILE'")
    parser.add_argument("--max-gap", type=float, default=0.25, help="interpolate marker gaps up to this many seconds")


def run(args: argparse.Namespace) -> int:
    from besdrake.cli import UserError
    from besdrake.mocap.preprocess import PreprocessError, preprocess
    from besdrake.mocap.qualisys import read_recording
    from besdrake.mocap.recording import MocapFormatError
    from besdrake.segmentation import SegmentationError

    if not args.file.is_file():
        raise UserError(f"{args.file}: no such file")
    if args.classifier and args.train:
        raise UserError("give either --classifier or --train, not both")
    if args.segmenter and args.method != "vmci":
        raise UserError("--segmenter is a tuned vMCI; it cannot be used with --method zvc")
    seg = _segmenter(args)
    try:
        rec = read_recording(args.file)
        pre = preprocess(rec, max_gap_s=args.max_gap)
        seg.fit(pre)
    except (MocapFormatError, PreprocessError, SegmentationError) as err:
        raise UserError(f"{args.file}: {err}") from None
    out = _segments(seg, pre, _classifier(args))
    report = {
        "file": str(args.file),
        "frequency_hz": pre.frequency,
        "n_frames": pre.n_frames,
        "method": args.method,
        "segmenter": seg.json_params(),
        "frame_numbering": "the file's own Frame column; adjacent segments share the border frame",
        "segments": out,
        "warnings": pre.warnings,
    }
    if args.json:
        print(json.dumps(report))
    else:
        for w in pre.warnings:
            print(f"warning: {w}")
        for i, item in enumerate(out):
            label = f"  {item['label']}" if "label" in item else ""
            print(f"{i:3d}  frames {item['start_frame']:6d}-{item['end_frame']:6d}  "
                  f"{item['start_time']:8.3f}-{item['end_time']:8.3f} s{label}")
    return 0


def _segmenter(args: argparse.Namespace):
    """The segmenter the arguments ask for: a tuned vMCI from --segmenter, vMCI or the zero-velocity baseline."""
    from besdrake.cli import UserError
    from besdrake.segmentation import VMCI, ZeroVelocitySegmenter

    if args.segmenter:
        from besdrake.segmentation import TunedVMCI

        try:
            return TunedVMCI.from_dict(json.loads(args.segmenter.read_text())).segmenter()
        except (OSError, ValueError) as err:
            raise UserError(f"--segmenter {args.segmenter}: {err}") from None
    return VMCI() if args.method == "vmci" else ZeroVelocitySegmenter()


def _classifier(args: argparse.Namespace):
    """The 1-NN classifier from --classifier (JSON) or trained on --train's labelled recordings; None without both."""
    from besdrake.cli import UserError
    from besdrake.segmentation.classification import SegmentClassifier

    try:
        if args.classifier:
            return SegmentClassifier.from_json(json.loads(args.classifier.read_text()))
        if args.train:
            from besdrake.segmentation.evaluation import labelled_recordings, labelled_segments

            return SegmentClassifier().fit(*labelled_segments(labelled_recordings(args.train)))
    except (OSError, ValueError) as err:
        raise UserError(f"classifier: {err}") from None
    return None


def _segments(seg, pre, clf) -> list[dict]:
    """One JSON row per segment: frames, times, the segment model and (with a classifier) its label."""
    from besdrake.segmentation.classification import ClassificationError, extract_segment

    out = []
    models = getattr(seg.result_, "segment_models", None) or [None] * len(seg.segments_)
    for (a, b), model in zip(seg.segments_, models):
        item = {"start_frame": int(pre.frames[a]), "end_frame": int(pre.frames[b]), "start_time": float(pre.time[a]), "end_time": float(pre.time[b])}
        if model is not None:
            item["model"] = model
        if clf is not None:
            try:
                item["label"] = str(clf.predict([extract_segment(pre, a, b)])[0])
            except ClassificationError as err:
                item["label"] = None
                item["label_error"] = str(err)
        out.append(item)
    return out
