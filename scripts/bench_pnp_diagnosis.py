#!/usr/bin/env python3
"""Benchmark ``diagnose`` on pick-and-place lab logs with seeded hidden truths (issue 25, item 6).

For every hidden truth (a virtual pick-and-place lab's ``effects``: the box's pose offset along x or y, low pad
friction, a heavy box, a joint-2 encoder offset, nothing, and the default lab's own mix, ``default_lab``, diagnosed
with pairs), the lab runs the designed picks
(:func:`besdrake.tasks.pick_and_place.diagnosis.design.diagnosis_plans`: ``--trials`` picks over spread place targets
and speeds, ``--repeats`` of them repeated) with its placement scatter and camera/encoder noise, and the diagnosis
names a cause among ``--candidates``. Printed per truth: the named cause and its parameters, the confidence, whether
it is right (the hidden effect named, or nothing claimed for a lab with nothing hidden) or honest (not right, but no
cause claimed with high or medium confidence), each named parameter against its hidden value
(``parameters_vs_hidden``: within 3 standard errors or not; ``right_with_a_value_off`` lists the right answers with a
value that is not), the held-out median final box position disparity before -> after (m), rollouts and wall seconds;
the last stdout line is one JSON object.

    python3 scripts/bench_pnp_diagnosis.py                       # every truth, about 5-10 min each on a busy core
    python3 scripts/bench_pnp_diagnosis.py --truths box_x,none --trials 8 --repeats 3
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

#: Hidden truths: the lab config's ``effects`` (absolute box mass kg and pad friction; registry effects otherwise) and
#: the registry effect that is the right answer (None: nothing hidden, the right answer claims no cause).
TRUTHS = {
    "box_x": ({"box_pose_offset": {"x": 0.015}}, "box_pose_offset"),
    "box_y": ({"box_pose_offset": {"y": -0.012}}, "box_pose_offset"),
    "pad_low": ({"pad_friction": 0.06}, "pad_friction"),
    "heavy": ({"box_mass": 0.7}, "box_mass"),
    "joint2": ({"joint_offset": {"joint2": 0.015}}, "joint_offset"),
    "none": ({}, None),
    # the default lab (diagrams/labs/pick_and_place_lab.yaml): its pads' friction (1.4x the model's 0.5) and its yaw
    # offset alone leave such logs as the nominal simulation does, so the right answer is the other two effects
    "default_lab": ({"box_pose_offset": {"x": 0.012, "y": -0.008, "yaw": 0.05}, "box_mass": 0.25, "pad_friction": 0.7},
                    ("box_pose_offset", "box_mass")),
}


def run_truth(name: str, args, rollout) -> dict:
    """Log the designed picks in a lab hiding ``TRUTHS[name]`` and diagnose the log."""
    from besdrake.diagnosis import diagnose
    from besdrake.sim.executors import make_executor
    from besdrake.sim.scenario import load_scenario
    from besdrake.tasks.pick_and_place.diagnosis.design import diagnosis_plans
    from besdrake.tasks.pick_and_place.lab import PickPlaceLab
    from besdrake.transfer.lab import SafetyGate

    hidden, right = TRUTHS[name]
    right_effects = sorted([right] if isinstance(right, str) else right or [])  # the effects a right answer names
    lab = PickPlaceLab({"name": f"bench_{name}", "scenario": "pick_and_place", "seed": args.seed, "effects": hidden}, rollout=rollout)
    plans = diagnosis_plans(args.trials, args.repeats, seed=args.seed, limits=lab.robot.limits, rollout=rollout)
    t0 = time.perf_counter()
    gate = SafetyGate(lab)
    log = [gate.execute(p, trial=i) for i, p in enumerate(plans)]
    t_lab = time.perf_counter() - t0
    scen = load_scenario("pick_and_place")
    t0 = time.perf_counter()
    with make_executor(args.backend, workers=args.workers, scenario=scen, limits="flag") as ex:
        pairs = args.pairs or len(right_effects) > 1  # a truth of two effects needs the pairs fitted
        d = diagnose(log, scenario=scen, candidates=args.candidates, pairs=pairs, structural=False, executor=ex, seed=args.seed)
    wall = time.perf_counter() - t0
    named = list(d.best.effects) if d.best is not None and d.explained else []
    claimed = bool(named) and d.confidence in ("high", "medium")
    correct = (sorted(named) == right_effects) if right_effects else not claimed
    # honest: nothing claimed with confidence where the answer is not right (e.g. "cannot tell", "not explained")
    honest = correct or not claimed
    g = d.gain
    return {
        "truth": name, "hidden": hidden, "right_answer": right, "named": named, "explained": d.explained, "confidence": d.confidence,
        "correct": bool(correct), "right_or_honest": bool(honest), "parameters": {k: round(v["value"], 5) for k, v in (d.best.to_dict()["parameters"].items() if d.best else [])},
        "parameters_vs_hidden": parameters_vs_hidden(d.best, lab.hidden_effects()) if d.best is not None and d.explained else [],
        "verdict": d.verdict, "disparity_before_m": None if g is None else g.median_disparity_before_m,
        "disparity_after_m": None if g is None else g.median_disparity_after_m, "n_heldout": None if g is None else g.n_heldout,
        "lab_success": sum(m.success for m in log), "rollouts": d.n_rollouts, "wall_s": round(wall, 1), "lab_s": round(t_lab, 1),
    }


def parameters_vs_hidden(cause, hidden: dict[str, dict[str, float]], k: float = 3.0) -> list[dict]:
    """Each named parameter against the lab's hidden value of it (the registry's, nominal where that effect or parameter
    is not hidden): ``consistent`` when they differ by at most ``k`` of the named value's standard error. A right cause
    can still carry a wrong value: a parameter that stands in for a hidden one the log does not tell from it."""
    out = []
    for p in cause.parameters:
        truth = hidden.get(p["effect"], {}).get(p["parameter"], p["nominal"])
        se = p.get("stderr")
        ok = bool(se is not None and np.isfinite(se) and abs(p["value"] - truth) <= k * se)
        out.append({"parameter": f"{p['effect']}.{p['parameter']}", "named": round(p["value"], 5), "stderr": None if se is None else round(se, 5),
                    "hidden": round(float(truth), 5), "consistent": ok})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--truths", default=",".join(TRUTHS), help=f"comma-separated, of {list(TRUTHS)}")
    ap.add_argument("--candidates", default="box_pose_offset,box_mass,pad_friction,joint_offset",
                    help="comma-separated candidate effects (default: the task's, without the slow actuator_lag)")
    ap.add_argument("--trials", type=int, default=10, help="picks per log (default 10)")
    ap.add_argument("--repeats", type=int, default=4, help="of them repeats of an earlier plan (default 4)")
    ap.add_argument("--pairs", action="store_true", help="also fit pairs of effects")
    ap.add_argument("--backend", default="serial", choices=("serial", "process"))
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help="also write the JSON here")
    args = ap.parse_args(argv)
    args.candidates = [c.strip() for c in args.candidates.split(",") if c.strip()]
    names = [t.strip() for t in args.truths.split(",") if t.strip()]
    bad = [t for t in names if t not in TRUTHS]
    if bad:
        ap.error(f"unknown truth(s) {bad}; known: {list(TRUTHS)}")
    from besdrake.tasks.pick_and_place.rollout import PickPlaceRollout

    rollout = PickPlaceRollout("pick_and_place")
    rows, t0 = [], time.perf_counter()
    for name in names:
        r = run_truth(name, args, rollout)
        rows.append(r)
        b, a = r["disparity_before_m"], r["disparity_after_m"]
        print(f"{name:8s} -> {'+'.join(r['named']) or 'nothing'} {r['parameters']} ({r['confidence']}) "
              f"{'RIGHT' if r['correct'] else ('honest' if r['right_or_honest'] else 'WRONG')}"
              f"{'' if all(p['consistent'] for p in r['parameters_vs_hidden']) else ' (a value off its hidden one)'}; disparity {b * 1000:.1f} -> {a * 1000:.1f} mm; "
              f"{r['rollouts']} rollouts, {r['wall_s']} s", file=sys.stderr, flush=True)
    out = {"config": {k: v for k, v in vars(args).items() if k != "out"}, "results": rows, "right": sum(r["correct"] for r in rows),
           "right_or_honest": sum(r["right_or_honest"] for r in rows), "confident_wrong": sum(not r["right_or_honest"] for r in rows),
           "right_with_a_value_off": [r["truth"] for r in rows if r["correct"] and not all(p["consistent"] for p in r["parameters_vs_hidden"])],
           "n": len(rows), "bench_wall_s": round(time.perf_counter() - t0, 1)}
    if args.out:
        with open(args.out, "w") as f:
            json.dump(out, f, indent=1)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
