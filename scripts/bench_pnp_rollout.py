#!/usr/bin/env python3
"""Benchmark one pick-and-place rollout (issue 24's target: a 6 s rollout in <= 1 s on one core).

Builds ``PickPlaceRollout`` for the scenario (default ``pick_and_place``: the iiwa 14), computes the scripted IK plan
(:mod:`besdrake.tasks.pick_and_place.scripted`) and times ``--repeats`` rollouts of it, reusing the Context. Prints
per rollout the outcome and, at the end, the median wall and CPU ms per rollout, the simulated time, the realtime
factor (simulated s per wall s) and the median ms per 6 simulated seconds; the last stdout line is one JSON object.
Run it on a quiet machine: wall times on shared cores are up to twice the CPU times.

    python3 scripts/bench_pnp_rollout.py --repeats 5
    python3 scripts/bench_pnp_rollout.py --robot panda --time-step 0.002
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402


def bench(scenario: str = "pick_and_place", robot: str | None = None, time_step: float | None = None, repeats: int = 5) -> dict:
    """Time ``repeats`` rollouts of the scripted plan; returns the figures as a dict."""
    from besdrake.sim.scenario import load_scenario
    from besdrake.tasks.pick_and_place.rollout import PickPlaceRollout
    from besdrake.tasks.pick_and_place.scripted import scripted_plan_for

    sc = load_scenario(scenario)
    if robot:
        sc = sc.with_robot(robot)
    if time_step:
        sc = sc.with_overrides(time_step=time_step)
    t0 = time.perf_counter()
    rollout = PickPlaceRollout(sc)
    build_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    plan = scripted_plan_for(rollout)
    ik_s = time.perf_counter() - t0
    wall, cpu, outcomes = [], [], []
    for _ in range(repeats):
        w, c = time.perf_counter(), time.process_time()
        out = rollout.rollout(plan)
        wall.append(time.perf_counter() - w)
        cpu.append(time.process_time() - c)
        outcomes.append(out)
        print(f"rollout: {wall[-1] * 1e3:.0f} ms wall, {cpu[-1] * 1e3:.0f} ms CPU, {out.sim_time:.2f} s simulated: {out.message} "
              f"(place error {out.place_error * 1e3:.1f} mm)", file=sys.stderr)
    sim_time = outcomes[-1].sim_time
    med_wall, med_cpu = float(np.median(wall)), float(np.median(cpu))
    return {
        "scenario": sc.name, "robot": sc.robot.name, "time_step_s": sc.time_step, "repeats": repeats,
        "build_s": round(build_s, 3), "ik_plan_s": round(ik_s, 3), "plan_duration_s": round(plan.duration, 3),
        "simulated_s": round(sim_time, 3), "median_ms_per_rollout": round(med_wall * 1e3, 1),
        "median_cpu_ms_per_rollout": round(med_cpu * 1e3, 1), "realtime_factor": round(sim_time / med_wall, 2),
        "median_ms_per_6s_simulated": round(med_wall * 6.0 / sim_time * 1e3, 1),
        "median_cpu_ms_per_6s_simulated": round(med_cpu * 6.0 / sim_time * 1e3, 1),
        "success": [o.success for o in outcomes], "place_error_m": outcomes[-1].place_error,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="pick_and_place")
    ap.add_argument("--robot", default=None, help="another robot (built-in name or robot YAML) in the same scene")
    ap.add_argument("--time-step", type=float, default=None, help="override the scenario's time step (s)")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    res = bench(args.scenario, args.robot, args.time_step, args.repeats)
    print(f"median {res['median_ms_per_rollout']:.0f} ms per rollout ({res['simulated_s']:.2f} s simulated; "
          f"{res['median_ms_per_6s_simulated']:.0f} ms per 6 s, CPU {res['median_cpu_ms_per_6s_simulated']:.0f} ms), "
          f"realtime factor {res['realtime_factor']:.1f}")
    print(json.dumps(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
