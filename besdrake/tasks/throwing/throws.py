"""A parametric default throw: an overhand swing of joints 2, 3 and 5 in the arm's vertical plane.

``default_throw(amplitude, yaw)`` returns a :class:`~besdrake.plan.MotionPlan` of ``duration`` s: the arm
holds the cocked :data:`START_POSE` (scoop level, the ball resting in it) for ``hold`` s, swings by
``amplitude * SWING`` along a minimum-jerk profile and holds the end pose. The swing time is chosen so that
the peak joint acceleration is always ``accel`` (default 19 rad/s^2, just inside the 20 rad/s^2 limit):

    T = sqrt(5.7735 * max|amplitude * SWING| / accel)

so a larger amplitude is a longer *and* faster swing (peak speed grows like sqrt(amplitude)). The ball is
pressed into the funnel while the arm accelerates and is catapulted out at the start of the deceleration,
which is equally hard for every amplitude: the release is decisive over the whole range, so the landing
point is a smooth, monotonic function of ``amplitude`` (about 0.15 -> 1 m ... 0.55 -> 2.5 m on the nominal
scenario). With a fixed swing *time* instead, slow throws decelerate gently, the ball dribbles out late in
a second regime, and the landing jumps between regimes. ``yaw`` (joint 1, rad) sets the direction.
The bench sweeps ``amplitude``; the CLI uses ``default_throw()`` when no plan is given.
"""

from __future__ import annotations

import numpy as np

from besdrake.plan import MotionPlan

#: Cocked start pose (rad): upper arm and forearm leaning back, wrist bent so the scoop faces up.
START_POSE = np.array([0.0, -0.45, -0.45, 0.0, 0.9, 0.0])
#: Swing (rad) at amplitude 1: upper arm and forearm swing forward, the wrist counter-rotates a little.
SWING = np.array([0.0, 0.75, 0.75, 0.0, -0.3, 0.0])
#: Peak |d^2 s/dx^2| of the minimum-jerk profile s(x) = 10x^3 - 15x^4 + 6x^5 on [0, 1].
MIN_JERK_PEAK_ACCEL = 10.0 / np.sqrt(3.0)


def swing_time(amplitude: float, accel: float = 19.0) -> float:
    """Duration (s) of the swing whose peak joint acceleration is ``accel`` rad/s^2."""
    return float(np.sqrt(MIN_JERK_PEAK_ACCEL * np.abs(SWING * amplitude).max() / accel))


def default_throw(
    amplitude: float = 0.35,
    yaw: float = 0.0,
    accel: float = 19.0,
    duration: float = 1.5,
    hold: float = 0.03,
    dt: float = 0.01,
) -> MotionPlan:
    """The default overhand throw (see module docstring); ``amplitude`` > 0 (1 = the full :data:`SWING`),
    ``yaw`` in rad, ``accel`` in rad/s^2, ``duration``/``hold``/``dt`` in s."""
    for name, v in (("amplitude", amplitude), ("yaw", yaw), ("accel", accel), ("duration", duration), ("hold", hold), ("dt", dt)):
        if not np.isfinite(v):
            raise ValueError(f"default_throw: {name} must be finite, got {v}")
    if amplitude <= 0 or accel <= 0 or dt <= 0 or hold < 0:
        raise ValueError(f"default_throw: amplitude, accel and dt must be positive and hold >= 0 (got {amplitude}, {accel}, {dt}, {hold})")
    T = swing_time(amplitude, accel)
    if hold + T > duration:
        raise ValueError(f"default_throw: hold {hold} s + swing {T:.3f} s exceed the duration {duration} s")
    start = START_POSE.copy()
    start[0] = yaw
    meta = {"generator": "default_throw", "amplitude": amplitude, "yaw": yaw, "accel": accel, "swing_time": T}
    return min_jerk_plan(start, SWING * amplitude, T, hold, duration, dt, meta)


def side_throw(
    amplitude: float = 0.35,
    yaw: float = 0.0,
    sweep: float = 0.0,
    twist4: float = 0.0,
    twist6: float = 0.0,
    start4: float = 0.0,
    start6: float = 0.0,
    accel: float = 19.0,
    duration: float = 1.5,
    hold: float = 0.03,
    dt: float = 0.01,
) -> MotionPlan:
    """A sideways variant of the default throw that moves every joint: the overhand swing of joints 2, 3 and 5
    (``amplitude`` x :data:`SWING`) while joint 1 sweeps by ``sweep`` (the ball gets a sideways velocity), joint 4
    turns the forearm by ``twist4`` and joint 6 the scoop about the flange by ``twist6`` (the release direction
    leans sideways), from the start pose turned to ``yaw`` with joints 4 and 6 at ``start4``/``start6`` (rad).
    The swing time keeps the peak joint acceleration at ``accel`` rad/s^2 (:func:`swing_time` of the largest joint
    move). Offsets of joints 1, 4 and 6, a tilted base or scoop show in these throws differently than in the planar
    ones (they turn the release direction in a plan-dependent way)."""
    for name, v in (("amplitude", amplitude), ("yaw", yaw), ("sweep", sweep), ("twist4", twist4), ("twist6", twist6),
                    ("start4", start4), ("start6", start6), ("accel", accel), ("duration", duration), ("hold", hold), ("dt", dt)):
        if not np.isfinite(v):
            raise ValueError(f"side_throw: {name} must be finite, got {v}")
    if amplitude <= 0 or accel <= 0 or dt <= 0 or hold < 0:
        raise ValueError(f"side_throw: amplitude, accel and dt must be positive and hold >= 0 (got {amplitude}, {accel}, {dt}, {hold})")
    delta = SWING * amplitude + np.array([sweep, 0.0, 0.0, twist4, 0.0, twist6])
    T = float(np.sqrt(MIN_JERK_PEAK_ACCEL * np.abs(delta).max() / accel))
    if hold + T > duration:
        raise ValueError(f"side_throw: hold {hold} s + swing {T:.3f} s exceed the duration {duration} s")
    start = START_POSE.copy()
    start[0], start[3], start[5] = yaw, start4, start6
    meta = {"generator": "side_throw", "amplitude": amplitude, "yaw": yaw, "sweep": sweep, "twist4": twist4, "twist6": twist6,
            "start4": start4, "start6": start6, "accel": accel, "swing_time": T}
    return min_jerk_plan(start, delta, T, hold, duration, dt, meta)


def min_jerk_plan(start: np.ndarray, delta: np.ndarray, move_time: float, hold: float, duration: float, dt: float, meta: dict) -> MotionPlan:
    """A plan of ``duration`` s sampled every ``dt`` s: hold ``start`` for ``hold`` s, move by ``delta`` (rad) along
    the minimum-jerk profile s(x) = 10x^3 - 15x^4 + 6x^5 in ``move_time`` s, hold the end pose."""
    t = np.arange(0.0, duration + dt / 2, dt)
    t[-1] = duration
    x = np.clip((t - hold) / move_time, 0.0, 1.0)
    s = 10 * x**3 - 15 * x**4 + 6 * x**5
    ds = (30 * x**2 - 60 * x**3 + 30 * x**4) / move_time
    return MotionPlan(t=t, q=start + np.outer(s, delta), qd=np.outer(ds, delta), meta=meta)


__all__ = ["default_throw", "side_throw", "min_jerk_plan", "swing_time", "START_POSE", "SWING"]
