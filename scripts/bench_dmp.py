"""Benchmark the DMP rollouts policy search depends on; prints JSON figures.

Figures: medians over repeated runs (ms), against ``movement_primitives`` (the formulation's
reference implementation) measured in the same run on the same DMP, and the largest difference
between the two rollouts. Usage: ``python3 scripts/bench_dmp.py [--repeats N]``.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
import types

import numpy as np

from besdrake.imitation import DMP, WEIGHTS_PER_JOINT, DMPParameterization, QuaternionDMP
from besdrake.imitation import quaternion as quat


def _median_ms(fn, repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times) * 1e3)


def _oracle():
    """``movement_primitives.dmp``, with placeholder pytransform3d modules if that is missing."""
    try:
        import pytransform3d.rotations  # noqa: F401
    except ImportError:
        package = types.ModuleType("pytransform3d")
        package.__path__ = []
        names = ["pytransform3d"] + [f"pytransform3d.{s}" for s in ("rotations", "batch_rotations", "transformations")]
        sys.modules.update({n: (package if n == "pytransform3d" else types.ModuleType(n)) for n in names})
        try:
            import movement_primitives.dmp as mp
        finally:
            for n in names:
                sys.modules.pop(n, None)
        return mp
    import movement_primitives.dmp as mp

    return mp


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=200, help="runs per besdrake figure (the oracle gets a tenth)")
    args = parser.parse_args()
    repeats = max(5, args.repeats)

    # A 1.5 s, 6-joint throw-like demonstration with a final velocity.
    t = np.linspace(0.0, 1.5, 301)
    s = t / t[-1]
    q = 0.3 * np.sin(np.pi * s[:, None] * (1 + 0.2 * np.arange(6)) + 0.4 * np.arange(6)) + s[:, None] ** 3
    dmp = DMP(6, WEIGHTS_PER_JOINT).fit(t, q)
    param = DMPParameterization(dmp)
    theta = param.to_vector()

    figures: dict[str, object] = {
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "note": "wall-clock medians; the machine may be shared",
        "dmp": {"n_dims": 6, "n_weights_per_dim": WEIGHTS_PER_JOINT, "execution_time_s": 1.5, "int_dt_s": dmp.int_dt},
    }
    mp = _oracle()
    for dt in (0.001, 0.002):
        ours = _median_ms(lambda: dmp.open_loop(dt), repeats)
        oracle = mp.DMPWithFinalVelocity(6, execution_time=1.5, dt=dt, n_weights_per_dim=WEIGHTS_PER_JOINT)
        oracle.imitate(t, q)
        theirs = _median_ms(lambda: oracle.open_loop(), max(3, repeats // 10))
        diff = float(np.max(np.abs(dmp.open_loop(dt).y - oracle.open_loop()[1])))
        figures[f"rollout_dt_{dt:g}"] = {
            "besdrake_ms": round(ours, 4),
            "movement_primitives_ms": round(theirs, 3),
            "speedup": round(theirs / ours, 1),
            "max_abs_difference_rad": diff,
        }
    figures["motion_plan_dt_0.002_ms"] = round(_median_ms(lambda: param.motion_plan(theta, 0.002), repeats), 4)
    figures["fit_301_samples_ms"] = round(_median_ms(lambda: DMP(6, WEIGHTS_PER_JOINT).fit(t, q), repeats), 4)
    y, yd = dmp.start, dmp.start_velocity
    figures["step_dt_0.001_us"] = round(1e3 * _median_ms(lambda: dmp.step(0.5, y, yd, 0.001), repeats), 2)

    r = np.column_stack((0.8 * np.sin(t), 0.5 * s**2, 1.2 * s**3))
    qdmp = QuaternionDMP(10).fit(t, quat.from_rotation_vector(r))
    figures["quaternion_rollout_dt_0.001_ms"] = round(_median_ms(lambda: qdmp.open_loop(0.001), max(5, repeats // 10)), 3)
    print(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
