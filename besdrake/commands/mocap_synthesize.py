"""``besdrake mocap synthesize``: write a synthetic throwing dataset (TSV + segmentations + truth)."""

from __future__ import annotations

import argparse
import json
import time

from besdrake.cli import UserError

COMMAND = ("mocap", "synthesize")
HELP = "generate synthetic overhand-throw recordings (Qualisys TSV) with ground-truth segments"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="output folder (created)")
    parser.add_argument("--subjects", type=int, default=10, help="number of subjects (default 10)")
    parser.add_argument("--experiments", type=int, default=3, help="experiments per subject (default 3)")
    parser.add_argument("--throws", type=int, default=8, help="throws per experiment (default 8)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--no-unlabeled", action="store_true", help="skip the unlabelled variant")
    parser.add_argument("--json", action="store_true", help="print a JSON summary")


def run(args: argparse.Namespace) -> int:
    from besdrake.tasks.throwing.demonstrator import generate_dataset

    for name in ("subjects", "experiments", "throws"):
        if getattr(args, name) < 1:
            raise UserError(f"--{name} must be at least 1, got {getattr(args, name)}")
    t0 = time.perf_counter()
    summary = generate_dataset(args.out, args.subjects, args.experiments, args.throws, args.seed,
                               unlabeled=not args.no_unlabeled)
    elapsed = time.perf_counter() - t0
    if args.json:
        print(json.dumps({"out_dir": summary.out_dir, "files": len(summary.files), "frequency_hz": summary.frequency,
                          "seed": summary.seed, "seconds": round(elapsed, 3)}))
    else:
        print(f"wrote {len(summary.files)} recordings to {summary.out_dir} in {elapsed:.1f} s")
    return 0
