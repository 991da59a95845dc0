#!/usr/bin/env python3
"""Benchmark: every grasp demonstration of the shared recordings imitated, planned and refined with CMA-ES in
simulation until a rollout succeeds (issue 24's target: within 100 generations). Prints one JSON line per
demonstration, then a summary: successes, median episodes to success, the initial plans' outcomes, wall time.

Usage: python3 scripts/bench_pnp_refine.py [--data DIR] [--robot NAME_OR_YAML] [--max-generations 100]
[--workers 2] [--out DIR] [--only subject1_run2,...] [--box-jitter 0.015]. A rerun with the same --out resumes every
search. Then ``bench_pnp_lab.py --skills OUT`` runs every refined grasp in the virtual lab.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from besdrake.sim.scenario import load_scenario
from besdrake.tasks.pick_and_place.demonstrations import extract_demonstrations
from besdrake.tasks.pick_and_place.imitation import GraspSkill
from besdrake.tasks.pick_and_place.refine import RefineSettings, refine_grasp
from besdrake.tasks.pick_and_place.rollout import PickPlaceRollout
from besdrake.tasks.pick_and_place.skill_plan import SkillPlanner

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "pick_and_place"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--robot", default=None)
    ap.add_argument("--max-generations", type=int, default=100)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--only", default=None, help="comma-separated recording names")
    ap.add_argument("--box-jitter", type=float, default=0.015,
                    help="m: a success must also work with the box this far off along x and y (learn.yaml's default)")
    args = ap.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_pnp_refine_"))
    scenario = load_scenario("pick_and_place")
    if args.robot:
        scenario = scenario.with_robot(args.robot)
        scenario_arg = str(out / "scenario.yaml")
        out.mkdir(parents=True, exist_ok=True)
        import yaml

        Path(scenario_arg).write_text(yaml.safe_dump(scenario.to_dict(), sort_keys=False))
    else:
        scenario_arg = "pick_and_place"
    planner = SkillPlanner.for_rollout(PickPlaceRollout(scenario))
    settings = RefineSettings(max_generations=args.max_generations, workers=args.workers, box_jitter=args.box_jitter)
    rows, t_all = [], time.perf_counter()
    files = sorted(args.data.glob("*.tsv"))
    if args.only:
        files = [f for f in files if f.stem in args.only.split(",")]
    for f in files:
        for i, d in enumerate(extract_demonstrations(f).demonstrations):
            t0 = time.perf_counter()
            res = refine_grasp(planner.adapt(GraspSkill.from_demonstration(d)), scenario_arg, out / f"{f.stem}_{i}",
                               settings)
            row = {"demo": f"{f.stem}_{i}", **res.summary(), "wall_s": round(time.perf_counter() - t0, 1)}
            rows.append(row)
            print(json.dumps(row), flush=True)
    hits = [r["episodes_to_success"] for r in rows if r["success"]]
    print(json.dumps({"robot": scenario.robot.name, "demonstrations": len(rows), "successes": len(hits),
                      "median_episodes_to_success": float(np.median(hits)) if hits else None,
                      "max_episodes_to_success": max(hits) if hits else None,
                      "initial_successes": sum(r["initial_success"] for r in rows),
                      "max_generations": args.max_generations, "wall_s": round(time.perf_counter() - t_all, 1),
                      "out": str(out)}))


if __name__ == "__main__":
    main()
