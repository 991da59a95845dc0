"""``besdrake demos pick_and_place PATH...``: grasp demonstrations from pick-and-place recordings."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

COMMAND = ("demos", "pick_and_place")
HELP = "grasp demonstrations (approach + transport, task frame) from pick-and-place recordings, reported per file"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("paths", type=Path, nargs="+", help="recordings (.tsv/.c3d) or folders of them")
    parser.add_argument("--out", type=Path, default=None,
                        help="folder for one .npz per demonstration (STEM_demoK.npz) and summary.json")
    parser.add_argument("--classifier", type=Path, default=None,
                        help="classifier .npz (default: the shipped one; retrain with "
                             "python -m besdrake.tasks.pick_and_place.train_classifier)")
    parser.add_argument("--reference", type=Path, default=None, metavar="LABELLED",
                        help="a recording with named markers of the same marker set: name the inputs' "
                             "unnamed trajectories by 'besdrake mocap label''s labeller fitted on it first")
    parser.add_argument("--no-join", action="store_true", help="do not join over-split movements before pairing")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _inputs(paths: list[Path]) -> list[Path]:
    from besdrake.cli import UserError

    files: list[Path] = []
    for p in paths:
        if p.is_dir():
            found = sorted([*p.glob("*.tsv"), *p.glob("*.c3d")])
            if not found:
                raise UserError(f"{p}: no .tsv or .c3d recording in this folder")
            files.extend(found)
        elif p.is_file():
            files.append(p)
        else:
            raise UserError(f"{p}: no such file or folder")
    return files


def run(args: argparse.Namespace) -> int:
    from besdrake.cli import UserError
    from besdrake.tasks.pick_and_place.classifier import load_classifier
    from besdrake.tasks.pick_and_place.demonstrations import extract_demonstrations

    files = _inputs(args.paths)
    try:
        clf = load_classifier(args.classifier)
    except ValueError as err:
        raise UserError(f"--classifier: {err}") from None
    labeler = None
    if args.reference is not None:
        from besdrake.mocap.labeling import MarkerLabeler
        from besdrake.mocap.qualisys import read_recording

        try:
            labeler = MarkerLabeler().fit(read_recording(args.reference))
        except (OSError, ValueError) as err:
            raise UserError(f"--reference {args.reference}: {err}") from None
    if args.out is not None:
        if args.out.exists() and not args.out.is_dir():
            raise UserError(f"--out {args.out}: exists and is not a folder")
        if any(f.parent.resolve() == args.out.resolve() for f in files):
            raise UserError(f"--out {args.out}: holds the input recordings; choose another folder")
        args.out.mkdir(parents=True, exist_ok=True)
    report = []
    for f in files:
        res = extract_demonstrations(f, classifier=clf, join=not args.no_join, labeler=labeler)
        entry = res.to_dict()
        if args.out is not None:
            entry["written"] = [str(d.to_npz(args.out / f"{f.stem}_demo{k}.npz")) for k, d in enumerate(res.demonstrations)]
        report.append(entry)
        if not args.json:
            _print_file(entry)
    summary = {"files": len(files), "pairs_found": sum(e["pairs_found"] for e in report),
               "demonstrations": sum(len(e["demonstrations"]) for e in report), "recordings": report}
    if args.out is not None:
        (args.out / "summary.json").write_text(json.dumps(summary, indent=1))
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"{summary['demonstrations']} demonstrations from {summary['pairs_found']} pairs in {len(files)} files")
    return 0


def _print_file(entry: dict) -> None:
    name = Path(entry["file"]).name
    print(f"{name}: {len(entry['demonstrations'])} demonstration(s) of {entry['pairs_found']} pair(s)")
    for d in entry["demonstrations"]:
        print(f"  approach {d['approach_frames']} transport {d['transport_frames']}: close {d['close_time']:.2f} s, "
              f"open {d['open_time']:.2f} s, table place {[round(v, 3) for v in d['table_box_position']]} m")
    for r in entry["rejected"]:
        print(f"  rejected approach {r['approach_frames']} transport {r['transport_frames']}: {r['reason']}")
    for p in entry["problems"]:
        print(f"  problem: {p}")
