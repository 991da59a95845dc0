#!/usr/bin/env python3
"""Post-hoc look at a refinement run's successes (issue 27): how far each successful throw's touchdown moves under the
lab's ball-placement scatter in simulation, and how the closest one (what a run keeps without a robust check) and the
most robust one (lowest RMS target distance over the 9 placements) repeat in the virtual lab against its noise floor.

    python3 scripts/bench_robust_selection.py RUN_FOLDER [RUN_FOLDER ...] [--max 12] [--repeats 20]

RUN_FOLDER: a refinement run's folder (problem.json, episodes.csv, details.csv), e.g. RUN/04_refine/run0.
Prints JSON.
"""

from __future__ import annotations

import argparse
import csv
import json
import logging
import sys
from pathlib import Path

import numpy as np


def _episodes(folder: Path) -> np.ndarray:
    with open(folder / "episodes.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    cols = sorted((k for k in rows[0] if k.startswith("p") and k[1:].isdigit()), key=lambda k: int(k[1:]))
    return np.array([[float(r[c]) for c in cols] for r in rows])


def main(argv: list[str] | None = None) -> int:
    from besdrake.search.refinement import RefinementProblem, params_key, read_details
    from besdrake.search.refinement.robust import RobustCheck
    from besdrake.sim import make_executor
    from besdrake.task import get_task
    from besdrake.tasks.throwing.repeatability import DEFAULT_LAB, lab_repeatability

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", type=Path, nargs="+")
    p.add_argument("--max", type=int, default=12, help="at most this many successes (the closest) per run")
    p.add_argument("--repeats", type=int, default=20)
    p.add_argument("--sd", type=float, default=0.002)
    args = p.parse_args(argv)
    logging.getLogger("drake").setLevel(logging.ERROR)
    out = []
    with make_executor("serial") as ex:
        check = RobustCheck.from_task(get_task("throwing"), ex.scenario, args.sd, radius=1.0)
        for folder in args.runs:
            problem = RefinementProblem.from_description(json.loads((folder / "problem.json").read_text()))
            problem.robust = None
            details = read_details(folder / "details.csv")
            X = _episodes(folder)
            recs = [details.get(params_key(x)) for x in X]
            ok = [i for i, r in enumerate(recs) if r is not None and r.success]
            ok = sorted(ok, key=lambda i: recs[i].distance)[: args.max]
            rows = []
            for i in ok:
                plan = problem.plan(X[i])
                outs = ex.evaluate([plan] * check.n_rollouts, effects=list(check.effects))
                pert = [problem.reward(plan, o, problem.robot.limits) for o in outs]
                r = check.combine(recs[i], pert)
                tds = np.array([q.touchdown if q.touchdown is not None else (np.nan, np.nan) for q in pert])
                rows.append({"episode": i + 1, "distance_m": recs[i].distance, "robust_distance_m": r.robust_distance,
                             "max_shift_m": float(np.nanmax(np.linalg.norm(tds - np.asarray(recs[i].touchdown), axis=1)))})
                print(folder, rows[-1], file=sys.stderr, flush=True)
            res = {"run": str(folder), "successes": sum(1 for r in recs if r is not None and r.success), "checked": rows}
            if rows:
                closest = min(rows, key=lambda r: r["distance_m"])
                robust = min(rows, key=lambda r: r["robust_distance_m"])
                for name, row in (("closest", closest), ("robust", robust)):
                    rep = lab_repeatability(problem.plan(X[row["episode"] - 1]), DEFAULT_LAB, args.repeats)
                    res[name] = row | {"lab": rep.summary()}
                    print(folder, name, res[name], file=sys.stderr, flush=True)
            out.append(res)
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
