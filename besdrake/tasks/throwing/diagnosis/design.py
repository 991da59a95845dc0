"""Experiment design for a diagnosis: which throws to log so that causes can be told apart.

Two things make a log diagnosable: *diversity* (release speeds, heights and directions spread out, so that
effects with different signatures, e.g. a higher base vs a slower drive, predict different touchdown
patterns) and *repeats* (the same plan thrown again measures the noise floor directly, the pure error
against which "explained" is tested). :func:`diagnosis_plans` gives both, from the smooth parametric default
throw (:func:`besdrake.tasks.throwing.throws.default_throw`, landing 1-2.5 m).

Some causes hardly move a throw at all: the default throw presses the ball into the funnel and catapults it
out along the wall normal, so ball-scoop friction changes its landing by millimetres. A *tilt probe*
(:func:`tilt_probe`) is a slow roll-out instead: the arm turns round (joint 1 near pi, so the ball leaves
forwards into the capture volume) and tips the scoop over with the wrist and elbow until the ball rolls out
over the rim. Whether the ball rolls or slides down the funnel wall is decided by friction (rolling needs
mu >= 2/7 tan of the wall's slope), so a slippery scoop releases it earlier and faster: 3-8 ms earlier and
6-7 cm/s faster at mu 0.3 than at the nominal 0.6 in the nominal simulation, while the ball's start in the
scoop is forgotten (it settles in the funnel before it rolls). ``diagnosis_plans(..., probes=k)`` mixes ``k``
of them into a log, each thrown twice: a repeated probe measures the lab's scatter without the placement's.

The default throw moves only joints 2, 3 and 5 in the arm's vertical plane, so an offset of joint 4 or 6, a
tilted scoop or base show only through what planar throws happen to show. *Sideways throws*
(:func:`besdrake.tasks.throwing.throws.side_throw`, ``diagnosis_plans(..., sideways=k)``) sweep joint 1 and turn joints 4 and
6 during the swing, from start poses with joints 4 and 6 turned (ranges :data:`SIDE_RANGES`): every joint a suspect
needs moves, within the safety gate's limits (every plan is checked against them).
"""

from __future__ import annotations

import numpy as np

from besdrake.plan import MotionPlan
from besdrake.robot import JointLimits
from besdrake.tasks.throwing.throws import START_POSE, default_throw, min_jerk_plan, side_throw

#: Ranges of the default-throw parameters used for diagnosis plans.
AMPLITUDE_RANGE = (0.25, 0.53)
YAW_RANGE = (-0.35, 0.35)
ACCEL_RANGE = (18.5, 19.0)
#: Sideways throws (:func:`besdrake.tasks.throwing.throws.side_throw`) in a diagnosis experiment by default (``besdrake diagnose
#: --design``, the benchmarks): a third of a 25-throw log's distinct throws.
DEFAULT_SIDEWAYS = 5
#: Uniform ranges (rad) of the sideways throws' joint-1 sweep, joint-4/6 twists during the swing and joint-4/6 start angles.
#: The start angles reach 0.5 rad (0.15 until session 33): a scoop tilted on its flange about its roll axis and an
#: offset of joint 6 turn the release almost alike in throws from the untwisted wrist (over a 25-throw log the part of
#: the tilt's chi-square a joint-6 offset cannot mimic was 2.5 % of it), while a throw started with joints 4 and 6 turned
#: the same way by 0.5 rad tells them apart 70 times more per throw (CALIBRATION.md, "Wider wrist starts").
SIDE_RANGES = {"sweep": (-0.3, 0.3), "twist4": (-0.25, 0.25), "twist6": (-0.25, 0.25), "start4": (-0.5, 0.5), "start6": (-0.5, 0.5)}
#: Sideways throws use amplitudes from here up (a slow swing from a turned wrist dropped the ball early: amplitude
#: 0.26, joints 4/6 started at +0.19/-0.18 rad).
SIDE_MIN_AMPLITUDE = 0.3
#: Tilt probes in a diagnosis experiment by default (``besdrake diagnose --design``, ``besdrake learn``).
DEFAULT_PROBES = 2
#: Tilt probes: (joint-1 yaw, wrist tilt, elbow/shoulder tilt, tilt time) of the first two; more alternate their yaw sign.
PROBES = ((2.8, -1.4, -0.15, 1.0), (-2.8, -1.2, -0.3, 1.2))


def tilt_probe(yaw: float = 2.8, wrist: float = -1.4, arm: float = -0.15, tilt_time: float = 1.0, hold: float = 0.05, duration: float = 2.0, dt: float = 0.01) -> MotionPlan:
    """A slow roll-out (see the module docstring): from the cocked start pose turned to ``yaw`` (rad), joints 2
    and 3 move by ``arm`` and the wrist (joint 5) by ``wrist`` (rad) along a minimum-jerk profile of
    ``tilt_time`` s after ``hold`` s, then the pose is held until ``duration`` s."""
    for name, v in (("yaw", yaw), ("wrist", wrist), ("arm", arm), ("tilt_time", tilt_time), ("hold", hold), ("duration", duration), ("dt", dt)):
        if not np.isfinite(v):
            raise ValueError(f"tilt_probe: {name} must be finite, got {v}")
    if tilt_time <= 0 or dt <= 0 or hold < 0 or hold + tilt_time > duration:
        raise ValueError(f"tilt_probe: need tilt_time, dt > 0, hold >= 0 and hold + tilt_time <= duration (got {tilt_time}, {dt}, {hold}, {duration})")
    start = START_POSE.copy()
    start[0] = yaw
    meta = {"generator": "tilt_probe", "yaw": yaw, "wrist": wrist, "arm": arm, "tilt_time": tilt_time}
    return min_jerk_plan(start, np.array([0.0, arm, arm, 0.0, wrist, 0.0]), tilt_time, hold, duration, dt, meta)


def diagnosis_plans(n: int = 25, repeats: int = 8, seed: int = 0, probes: int = 0, sideways: int = 0,
                    limits: JointLimits | None = None) -> list[MotionPlan]:
    """``n`` plans in random order: ``n - repeats - probes`` distinct throws (stratified amplitudes, random yaw and
    acceleration; ``sideways`` of them, spread over the amplitudes, are sideways throws that also move joints 1, 4
    and 6, :func:`side_plan`), ``probes`` tilt probes (:data:`PROBES`) and ``repeats`` plans thrown a second time:
    every probe first (while the repeats last), then randomly chosen throws. Seeded with
    ``numpy.random.default_rng(seed)``; ``probes=0, sideways=0`` gives the planar throws-only design of earlier
    versions (the same plans for the same seed). ``limits``: the robot's joint limits, which sideways throws keep."""
    if n < 2 or not (0 <= repeats <= n // 2) or not (0 <= probes <= n - repeats - 2) or not (0 <= sideways <= n - repeats - probes):
        raise ValueError(f"diagnosis_plans: need n >= 2, 0 <= repeats <= n/2, 0 <= probes <= n - repeats - 2 and 0 <= sideways <= n - repeats - probes, "
                         f"got n={n}, repeats={repeats}, probes={probes}, sideways={sideways}")
    if sideways and limits is None:
        raise ValueError("diagnosis_plans: sideways throws need the robot's joint limits (limits=robot.limits)")
    rng = np.random.default_rng(seed)
    k = n - repeats - probes
    lo, hi = AMPLITUDE_RANGE
    amps = lo + (hi - lo) * (np.arange(k) + rng.uniform(0.1, 0.9, k)) / k
    yaws = rng.uniform(*YAW_RANGE, k)
    accels = rng.uniform(*ACCEL_RANGE, k)
    plans = []
    # Sideways throws spread over the stratified amplitudes (their own generator, so the planar draws stay as before).
    # Slow sideways swings from a turned wrist can tip the ball out before the throw: they take the amplitudes from
    # SIDE_MIN_AMPLITUDE up where there are enough of them.
    fast = np.nonzero(amps >= SIDE_MIN_AMPLITUDE)[0] if np.sum(amps >= SIDE_MIN_AMPLITUDE) >= sideways else np.arange(k)
    side = set(fast[np.linspace(0, len(fast) - 1, sideways).round().astype(int)].tolist()) if sideways else set()
    side_rng = np.random.default_rng([seed, 1])
    for i, (a, y, c) in enumerate(zip(amps, yaws, accels)):
        p = side_plan(float(a), float(y), float(c), side_rng, limits) if i in side else default_throw(amplitude=float(a), yaw=float(y), accel=float(c))
        p.meta["name"] = f"diag_{i:02d}"
        plans.append(p)
    # Every probe is thrown twice (while the repeats last): its own scatter, without the placement's, is measured.
    probe_repeats = min(probes, repeats)
    rep = rng.choice(k, size=repeats - probe_repeats, replace=False) if repeats > probe_repeats else np.zeros(0, int)
    allp = plans + [plans[int(i)] for i in rep]
    for j in range(probes):
        yaw, wrist, arm, tt = PROBES[j % len(PROBES)]
        p = tilt_probe(yaw=yaw if (j // len(PROBES)) % 2 == 0 else -yaw, wrist=wrist, arm=arm, tilt_time=tt)
        p.meta["name"] = f"probe_{j:02d}"
        allp += [p] * (2 if j < probe_repeats else 1)
    order = rng.permutation(len(allp))
    return [allp[int(i)] for i in order]


def side_plan(amplitude: float, yaw: float, accel: float, rng: np.random.Generator, limits: JointLimits,
              tries: int = 20) -> MotionPlan:
    """A sideways throw (:func:`~besdrake.tasks.throwing.throws.side_throw`) with its sweep, twists and start angles drawn from
    :data:`SIDE_RANGES`, redrawn until it is within the joint position, velocity and acceleration limits (the safety
    gate's check); the planar default throw if no draw is."""
    for _ in range(tries):
        kw = {name: float(rng.uniform(lo, hi)) for name, (lo, hi) in SIDE_RANGES.items()}
        p = side_throw(amplitude=amplitude, yaw=yaw, accel=accel, **kw)
        if not plan_limits_exceeded(p, limits):
            return p
    return default_throw(amplitude=amplitude, yaw=yaw, accel=accel)


def sample_plans(limits: JointLimits, n_planar: int = 4, n_side: int = 4, seed: int = 0) -> list[MotionPlan]:
    """Plans within the robot's ``limits`` (what the safety gate allows) that together move every joint: planar default
    throws over the amplitude range, sideways throws (joints 1, 4, 6 too) and the two tilt probes (the plan sample of
    the structural identifiability, :mod:`besdrake.diagnosis.identifiability`)."""
    rng = np.random.default_rng(seed)
    lo, hi = AMPLITUDE_RANGE
    plans = [default_throw(amplitude=float(a), yaw=float(rng.uniform(*YAW_RANGE))) for a in np.linspace(lo, hi, n_planar)]
    plans += [side_plan(float(a), float(rng.uniform(*YAW_RANGE)), 19.0, rng, limits) for a in np.linspace(SIDE_MIN_AMPLITUDE, hi, n_side)]
    plans += [tilt_probe(*p[:3], tilt_time=p[3]) for p in PROBES]
    return [p for p in plans if not plan_limits_exceeded(p, limits)]


def plan_limits_exceeded(plan: MotionPlan, limits: JointLimits) -> bool:
    """True when ``plan`` exceeds one of the robot's joint position, velocity or acceleration ``limits`` (what the
    safety gate refuses)."""
    return not plan.check_limits(limits).ok


__all__ = ["diagnosis_plans", "sample_plans", "side_plan", "plan_limits_exceeded", "SIDE_RANGES", "DEFAULT_SIDEWAYS", "tilt_probe", "PROBES", "DEFAULT_PROBES", "AMPLITUDE_RANGE", "YAW_RANGE", "ACCEL_RANGE"]
