"""``besdrake eval segmentation --data DIR``: border precision/recall/F1 against manual segmentations."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

COMMAND = ("eval", "segmentation")
HELP = "score vMCI (and the zero-velocity baseline) against the manual segmentations in a folder"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", type=Path, required=True,
                        help="folder of *.tsv recordings with *_manually_segmented.json beside them")
    parser.add_argument("--json", action="store_true", help="print the metrics as one JSON object")
    parser.add_argument("--tolerances", type=float, nargs="+", default=[0.1, 0.2], help="seconds")
    parser.add_argument("--no-baseline", action="store_true", help="skip the zero-velocity baseline")
    parser.add_argument("--tune-on", type=Path, default=None, metavar="DIR",
                        help="also score vMCI with priors and border rules chosen on the labelled recordings "
                             "in DIR (another subject: tuned on one, scored on the other)")
    parser.add_argument("--save-segmenter", type=Path, default=None, metavar="FILE",
                        help="with --tune-on: write the tuned segmenter as JSON (for 'besdrake segment --segmenter')")
    parser.add_argument("--conventions", action="store_true",
                        help="also measure how the manual segmentations place their borders (pauses left between "
                             "segments, hand speed at the borders, distance from speed minima), for --data and "
                             "--tune-on: rules learned on one annotator carry over only as far as these agree")


def run(args: argparse.Namespace) -> int:
    from besdrake.cli import UserError
    from besdrake.segmentation import VMCI, ZeroVelocitySegmenter
    from besdrake.segmentation.evaluation import evaluate_segmenter, labelled_recordings

    try:
        recs = labelled_recordings(args.data)
    except (OSError, ValueError) as err:
        raise UserError(str(err)) from None
    if any(t <= 0 for t in args.tolerances):
        raise UserError("tolerances must be positive seconds")
    if args.save_segmenter and not args.tune_on:
        raise UserError("--save-segmenter needs --tune-on DIR")
    methods = {"vmci": VMCI()}
    if not args.no_baseline:
        methods["zero_velocity"] = ZeroVelocitySegmenter()
    report = {"data": str(args.data), "n_recordings": len(recs)}
    conventions = {}
    if args.tune_on:
        from besdrake.segmentation import tune_vmci

        try:
            train = labelled_recordings(args.tune_on)
            tuned = tune_vmci(train)
        except (OSError, ValueError) as err:
            raise UserError(f"--tune-on: {err}") from None
        methods["vmci_tuned"] = tuned.segmenter()
        report["tuned_on"] = str(args.tune_on)
        report["tuned"] = tuned.to_dict()
        if args.save_segmenter:
            from besdrake._io import write_json

            write_json(args.save_segmenter, tuned.to_dict())
    try:
        for name, seg in methods.items():
            report[name] = evaluate_segmenter(seg, recs, args.tolerances).to_dict()
        if args.conventions:
            from besdrake.segmentation.conventions import annotation_conventions

            conventions["data"] = annotation_conventions(recs).to_dict()
            if args.tune_on:
                conventions["tune_on"] = annotation_conventions(train).to_dict()
            report["annotation_conventions"] = conventions
    except ValueError as err:
        raise UserError(str(err)) from None
    if args.json:
        print(json.dumps(report))
    else:
        for name in methods:
            r = report[name]
            for tol, s in r["scores"].items():
                print(f"{name:14s} +-{tol} s  P {s['precision']:.3f}  R {s['recall']:.3f}  F1 {s['f1']:.3f}")
        for which, c in conventions.items():
            print(f"conventions of {which}: {c['n_borders']} borders, {c['pause_edge_share']:.0%} at the edges of "
                  f"{c['n_pauses']} pauses; speed at a border / peak: median {c['speed_fraction_quartiles'][1]:.3f}; "
                  f"within 0.1 s of a speed minimum: {c['near_minimum_share']:.0%}")
    return 0
