"""Benchmark of ``besdrake diagnose`` on labs with TWO hidden effects, with and without the forward pair step.

Each trial hides one pair of registry effects (cycled through :data:`PAIRS`), each at a realistic magnitude drawn as
in ``bench_diagnosis.py`` (seeded), runs the virtual lab on the 25-throw diagnosis design (8 repeats) and diagnoses the
full log twice: as shipped, and with the forward selection of pairs turned off (``settings.FORWARD_PAIRS = False``, the
behaviour before it), sharing the rollout cache (so the second wall time is not comparable). Prints one JSON line per
diagnosis on stderr and a summary: the share of trials whose best cause is exactly the hidden pair, per setting.

    python3 scripts/bench_diagnosis_pairs.py --trials 6 --workers 2 > pairs.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

#: Pairs of effects the benchmark hides (each at least partly visible in a 25-throw full log at realistic values).
PAIRS = (("base_offset", "actuator_lag"), ("joint_offset", "air_drag"), ("base_offset", "air_drag"), ("actuator_lag", "ball"),
         ("gain_scale", "base_offset"), ("joint_offset", "actuator_lag"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=len(PAIRS))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--probes", type=int, default=None, help="tilt probes among the 25 throws (default: the diagnosis design's, 2; 0: throws only)")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_diagnosis as single

    from besdrake.diagnosis import diagnose, diagnosis_plans, settings
    from besdrake.tasks.throwing.diagnosis.design import DEFAULT_PROBES
    from besdrake.sim.executors import make_executor
    from besdrake.task import effects_for
    from besdrake.tasks.throwing.lab import VirtualLab

    registry = effects_for("throwing")  # the registry's effects that act on throws
    rows = []
    t_bench = time.perf_counter()
    shipped = settings.FORWARD_PAIRS
    try:
        with make_executor("process", workers=args.workers, scenario="nominal", limits="flag") as ex:
            for i in range(args.trials):
                a, b = PAIRS[i % len(PAIRS)]
                rng = np.random.default_rng([args.seed, i])
                hidden = {**single._draw(a, rng), **single._draw(b, rng)}
                lab_seed = 1000 * args.seed + i
                lab = VirtualLab({"name": "bench_pair_lab", "effects": hidden, "seed": lab_seed})
                ms = [lab.execute(p) for p in diagnosis_plans(25, 8, seed=lab_seed, probes=DEFAULT_PROBES if args.probes is None else args.probes)]
                cache: dict = {}
                for forward in (True, False):
                    settings.FORWARD_PAIRS = forward
                    t0 = time.perf_counter()
                    d = diagnose(ms, candidates=registry, executor=ex, cache=cache, seed=i)
                    row = {"trial": i, "hidden": hidden, "forward_pairs": forward, "best": list(d.best.effects), "right": set(d.best.effects) == set(hidden),
                           "explained": d.explained, "confidence": d.confidence, "fitted": d.refined_effects(),
                           "alternatives": [x["b"] for x in d.indistinguishable], "wall_s": time.perf_counter() - t0}
                    rows.append(row)
                    print(json.dumps(row, default=float), file=sys.stderr, flush=True)
    finally:
        settings.FORWARD_PAIRS = shipped
    out = {"config": vars(args), "bench_wall_s": time.perf_counter() - t_bench, "trials": rows}
    for forward in (True, False):
        sel = [r for r in rows if r["forward_pairs"] == forward]
        key = "with_forward_pairs" if forward else "without_forward_pairs"
        out[key] = {"right_pair_rate": float(np.mean([r["right"] for r in sel])) if sel else None,
                    "right_pair_high_confidence": int(sum(r["right"] and r["confidence"] == "high" for r in sel)),
                    "wrong_with_high_confidence": int(sum((not r["right"]) and r["confidence"] == "high" for r in sel)), "n": len(sel)}
    print(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
