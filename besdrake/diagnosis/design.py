"""Experiment design for a diagnosis: which throws to log so that causes can be told apart.

Two things make a log diagnosable: *diversity* (release speeds, heights and directions spread out, so that
effects with different signatures, e.g. a higher base vs a slower drive, predict different touchdown
patterns) and *repeats* (the same plan thrown again measures the noise floor directly, the pure error
against which "explained" is tested). :func:`diagnosis_plans` gives both, from the smooth parametric default
throw (:func:`besdrake.sim.throws.default_throw`, landing 1-2.5 m).
"""

from __future__ import annotations

import numpy as np

from besdrake.plan import MotionPlan
from besdrake.sim.throws import default_throw

#: Ranges of the default-throw parameters used for diagnosis plans.
AMPLITUDE_RANGE = (0.25, 0.53)
YAW_RANGE = (-0.35, 0.35)
ACCEL_RANGE = (18.5, 19.0)


def diagnosis_plans(n: int = 25, repeats: int = 8, seed: int = 0) -> list[MotionPlan]:
    """``n`` plans: ``n - repeats`` distinct throws (stratified amplitudes, random yaw and acceleration) plus
    ``repeats`` of them thrown a second time, in random order. Seeded with ``numpy.random.default_rng(seed)``."""
    if n < 2 or not (0 <= repeats <= n // 2):
        raise ValueError(f"diagnosis_plans: need n >= 2 and 0 <= repeats <= n/2, got n={n}, repeats={repeats}")
    rng = np.random.default_rng(seed)
    k = n - repeats
    lo, hi = AMPLITUDE_RANGE
    amps = lo + (hi - lo) * (np.arange(k) + rng.uniform(0.1, 0.9, k)) / k
    yaws = rng.uniform(*YAW_RANGE, k)
    accels = rng.uniform(*ACCEL_RANGE, k)
    plans = []
    for i, (a, y, c) in enumerate(zip(amps, yaws, accels)):
        p = default_throw(amplitude=float(a), yaw=float(y), accel=float(c))
        p.meta["name"] = f"diag_{i:02d}"
        plans.append(p)
    rep = rng.choice(k, size=repeats, replace=False) if repeats else np.zeros(0, int)
    allp = plans + [plans[int(i)] for i in rep]
    order = rng.permutation(len(allp))
    return [allp[int(i)] for i in order]


__all__ = ["diagnosis_plans", "AMPLITUDE_RANGE", "YAW_RANGE", "ACCEL_RANGE"]
