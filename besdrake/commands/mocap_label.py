"""``besdrake mocap label``: name the unnamed marker trajectories of a recording."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from besdrake._io import OutputError, check_output
from besdrake.cli import UserError

COMMAND = ("mocap", "label")
HELP = "label unnamed marker trajectories using one labelled reference recording; fill short gaps"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="recording with unnamed trajectories (.tsv or .c3d)")
    parser.add_argument("--reference", required=True, help="labelled recording of the same marker set (.tsv or .c3d)")
    parser.add_argument("--out", required=True, help="labelled output recording (.tsv or .c3d)")
    parser.add_argument("--max-gap", type=float, default=0.25, help="longest gap to fill, seconds (default 0.25)")
    parser.add_argument("--no-fill", action="store_true", help="do not fill gaps")
    parser.add_argument("--json", action="store_true", help="print a JSON summary")


def run(args: argparse.Namespace) -> int:
    from besdrake.mocap.labeling import LabelingError, MarkerLabeler
    from besdrake.mocap.qualisys import read_recording, write_recording
    from besdrake.mocap.recording import MocapFormatError

    for p in (args.file, args.reference):
        if not Path(p).is_file():
            raise UserError(f"no such file: {p}")
    if not math.isfinite(args.max_gap) or args.max_gap < 0:
        raise UserError(f"--max-gap must be a number of seconds >= 0, got {args.max_gap}")
    if Path(args.out).suffix.lower() not in (".tsv", ".c3d"):
        raise UserError(f"--out must end in .tsv or .c3d, got {args.out}")
    check_output(args.out, inputs=[args.file, args.reference])
    try:
        reference = read_recording(args.reference)
        recording = read_recording(args.file)
        labeler = MarkerLabeler(max_gap_s=args.max_gap).fit(reference)
        result = labeler.predict(recording, fill=not args.no_fill)
    except (MocapFormatError, LabelingError, OutputError) as err:
        raise UserError(str(err)) from None
    write_recording(result.recording, args.out)
    summary = {"file": str(args.file), "reference": str(args.reference), "out": str(args.out), **result.summary()}
    if args.json:
        print(json.dumps(summary))
    else:
        print(
            f"labelled {summary['frames']} frames: {summary['tracklets']} trajectories, "
            f"{summary['ghost_tracklets']} rejected as ghosts; {summary['gaps_filled']} gaps filled, "
            f"{summary['gaps_flagged']} flagged; wrote {args.out}"
        )
        for w in result.warnings:
            print(f"warning: {w}")
    return 0
