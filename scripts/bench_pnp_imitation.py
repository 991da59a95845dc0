#!/usr/bin/env python3
"""Benchmark: every grasp demonstration of the shared recordings imitated and planned on robots (prints JSON).

Per robot and demonstration: the DMP's imitation error against the demonstrated grasp point path
(``dmp_err_mm``: mean / max, scene places = demonstrated ones), the plan's tool path against that path
where IK reached the pose (``plan_err_mm``: includes the approach's goal moved onto the box), the IK
poses and how many were unreachable, the orientation residual (median / max, deg), IK jumps, the
temporal scaling factor and what limits it, the plan's duration, whether the plan keeps the limits,
and the wall time of ``grasp_plan``.

Usage: python3 scripts/bench_pnp_imitation.py [--data DIR] [--robot NAME_OR_YAML ...] [--x-base-task X Y Z YAW]
[--start demonstration|home] [--ik-dt 0.04]. ``--robot test_gripper_arm`` is the tests' 7-joint arm with two
fingers (iiwa 14 link lengths; written to a temporary folder). ``--x-base-task``: the task frame (the box on
the shelf, x towards the table) in the robot's base frame, m and rad (yaw about z); default per robot below.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw

from besdrake.embodiment.kinematics import welded_plant
from besdrake.robot import load_robot
from besdrake.tasks.pick_and_place.classifier import load_classifier
from besdrake.tasks.pick_and_place.demonstrations import extract_demonstrations
from besdrake.tasks.pick_and_place.grasp_plan import grasp_plan
from besdrake.tasks.pick_and_place.imitation import GraspSkill, grasp_point_path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "pick_and_place"
DEFAULT_X = {"compi": (0.75, 0.55, 0.5, -np.pi / 2)}
FALLBACK_X = (0.7, 0.6, 0.4, -np.pi / 2)


def _robot(name: str):
    if name == "test_gripper_arm":
        sys.path.insert(0, str(REPO / "tests"))
        from gripper_arm import write_gripper_arm

        return load_robot(write_gripper_arm(Path(tempfile.mkdtemp())))
    return load_robot(name)


def _row(d, robot, model, X, start: str, ik_dt: float) -> dict:
    path, _ = grasp_point_path(d)
    traj = GraspSkill.from_demonstration(d).rollout(1.0 / 120)
    dmp = np.linalg.norm(np.array([np.interp(d.t, traj.t, traj.pose[:, j]) for j in range(3)]).T - path, axis=1)
    t0 = time.perf_counter()
    gp = grasp_plan(d, robot, X, model=model, start=start, ik_dt=ik_dt)
    wall = time.perf_counter() - t0
    ok = gp.ik.reachable
    tool = np.array([model.tcp_pose(q).translation() for q in gp.ik.q])
    demo = np.array([np.interp(gp.ik.t, d.t, c) for c in (path @ X.rotation().matrix().T + X.translation()).T]).T
    err = np.linalg.norm(tool - demo, axis=1)[ok] if start == "demonstration" else np.array([np.nan])
    ang = np.degrees(gp.ik.angle_residual)
    return {"demo": Path(d.source).stem, "demo_duration_s": round(float(d.t[-1]), 2),
            "dmp_err_mm": [round(float(dmp.mean()) * 1e3, 1), round(float(dmp.max()) * 1e3, 1)],
            "plan_err_mm": [round(float(err.mean()) * 1e3, 1), round(float(err.max()) * 1e3, 1)] if ok.any() else None,
            "ik_poses": int(len(ok)), "ik_unreachable": int((~ok).sum()),
            "angle_residual_deg": [round(float(np.median(ang)), 1), round(float(ang.max()), 1)],
            "jumps": len(gp.ik.jumps()), "time_scale": round(gp.scaling.factor, 2), "limiting": gp.scaling.limiting,
            "plan_duration_s": round(gp.plan.duration, 2), "limits_ok": gp.plan.check_limits(robot.limits).ok,
            "wall_s": round(wall, 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--robot", action="append", default=None)
    ap.add_argument("--x-base-task", type=float, nargs=4, default=None)
    ap.add_argument("--start", default="demonstration", choices=["demonstration", "home"])
    ap.add_argument("--ik-dt", type=float, default=0.04)
    args = ap.parse_args()
    clf = load_classifier()
    demos = [d for f in sorted(args.data.glob("*.tsv")) for d in extract_demonstrations(f, classifier=clf).demonstrations]
    out = {}
    for name in args.robot or ["test_gripper_arm", "compi"]:
        robot = _robot(name)
        x, y, z, yaw = args.x_base_task or DEFAULT_X.get(robot.name, FALLBACK_X)
        X = RigidTransform(RollPitchYaw(0, 0, yaw), [x, y, z])
        model = welded_plant(robot)
        rows = [_row(d, robot, model, X, args.start, args.ik_dt) for d in demos]
        for r in rows:
            print(json.dumps({"robot": robot.name, **r}), flush=True)
        out[robot.name] = {
            "x_base_task": [x, y, z, yaw], "demonstrations": len(rows),
            "unreachable_total": sum(r["ik_unreachable"] for r in rows), "poses_total": sum(r["ik_poses"] for r in rows),
            "recordings_with_unreachable": sum(r["ik_unreachable"] > 0 for r in rows),
            "with_jumps": sum(r["jumps"] > 0 for r in rows), "limits_ok": sum(r["limits_ok"] for r in rows),
            "plan_duration_s_median": float(np.median([r["plan_duration_s"] for r in rows])),
            "time_scale_median": float(np.median([r["time_scale"] for r in rows])),
            "wall_s_median": float(np.median([r["wall_s"] for r in rows])),
        }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
