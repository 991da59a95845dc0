#!/usr/bin/env python3
"""Rollout benchmark: prints one JSON object (see besdrake/sim/bench.py). Same as `besdrake bench rollout --json`."""

from __future__ import annotations

import argparse
import json
import sys

from besdrake.tasks.throwing.bench import run_bench


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="fewer throws and a batch of 16 (smoke test)")
    ap.add_argument("--out", default="runs/bench", help="folder for bench_rollout.json and landing_sweep.png")
    args = ap.parse_args(argv)
    res = run_bench(quick=args.quick, out_dir=args.out, progress=lambda m: print(m, file=sys.stderr))
    print(json.dumps(res.to_dict()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
