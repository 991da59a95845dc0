"""``besdrake bench rollout``: fidelity, speed and parallel speed-up of the throwing simulation."""

from __future__ import annotations

import argparse
import json
import sys

COMMAND = ("bench", "rollout")
HELP = "benchmark the rollout: landing error vs a 1 ms step, ms per throw, 2-worker speed-up, sweep plot"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--quick", action="store_true", help="fewer throws and a batch of 16 (smoke test)")
    parser.add_argument("--out", default="runs/bench", help="folder for bench_rollout.json and landing_sweep.png")
    parser.add_argument("--scenario", default="nominal", help="scenario name or YAML path")


def run(args: argparse.Namespace) -> int:
    from besdrake.cli import UserError
    from besdrake.tasks.throwing.bench import run_bench
    from besdrake.sim.scenario import ScenarioError

    try:
        res = run_bench(quick=args.quick, out_dir=args.out, scenario=args.scenario, progress=lambda m: print(m, file=sys.stderr))
    except ScenarioError as err:
        raise UserError(str(err)) from err
    d = res.to_dict()
    if args.json:
        print(json.dumps(d))
        return 0
    for key in ("max_landing_error_m", "ms_per_rollout", "rollouts_per_s", "speedup_2_workers"):
        tgt = res.targets.get(key)
        ok = res.passed.get(key)
        print(f"{key:22s} {d[key]:10.4g}" + ("" if tgt is None else f"   target {tgt:g}  {'PASS' if ok else 'MISS'}"))
    print(f"landing range          {res.landing_range_m[0]:.3f} .. {res.landing_range_m[1]:.3f} m, monotonic: {res.landing_monotonic}")
    print(f"plot                   {res.plot}")
    return 0
