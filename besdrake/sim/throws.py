"""A parametric default throw: an overhand swing of joints 2, 3 and 5 in the arm's vertical plane.

``default_throw(speed, yaw)`` returns a :class:`~besdrake.plan.MotionPlan` of ``duration`` s in which
all swinging joints follow one scalar swing coordinate s(t) along the direction :data:`SWING`:

1. hold the cocked :data:`START_POSE` (scoop level, the ball resting in it) for ``hold`` s;
2. accelerate in ``accel_time`` s to the peak joint speed ``speed * 3.14 rad/s`` (raised-cosine velocity);
3. brake with a raised-cosine velocity profile whose peak deceleration is ``brake`` rad/s^2 whatever the speed;
4. hold the end pose.

The ball is pressed into the scoop while the arm accelerates and is catapulted out of the funnel at the
start of the braking phase, because the braking deceleration at the scoop (~1.5 g at ``brake`` = 16 rad/s^2)
always exceeds gravity: the release is decisive for every speed, so the landing point is a smooth,
monotonic function of ``speed`` (a throw that merely decelerated gently would let the ball dribble out
late, in a second regime). ``yaw`` (joint 1) sets the direction. The bench sweeps ``speed`` to land
between 1 and 2.5 m; the CLI uses ``default_throw()`` when no plan is given.
"""

from __future__ import annotations

import numpy as np

from besdrake import robot
from besdrake.plan import MotionPlan

#: Cocked start pose (rad): upper arm and forearm leaning back, wrist bent so the scoop faces up.
START_POSE = np.array([0.0, -0.45, -0.45, 0.0, 0.9, 0.0])
#: Direction of the swing in joint space (rad per unit of the swing coordinate); joints 2 and 3 move at
#: the peak speed, the wrist (joint 5) counter-rotates a little so the scoop stays open upward.
SWING = np.array([0.0, 1.0, 1.0, 0.0, -0.4, 0.0])


def _profile(t: np.ndarray, hold: float, accel_time: float, v_peak: float, brake: float) -> tuple[np.ndarray, np.ndarray]:
    """Swing coordinate s(t) and its rate for the raised-cosine accelerate/brake profile."""
    t_brake = np.pi * v_peak / (2.0 * brake)
    tau = t - hold
    s = np.zeros_like(t)
    v = np.zeros_like(t)
    a = (tau > 0) & (tau <= accel_time)
    x = tau[a] / accel_time
    v[a] = 0.5 * v_peak * (1 - np.cos(np.pi * x))
    s[a] = 0.5 * v_peak * accel_time * (x - np.sin(np.pi * x) / np.pi)
    s_a = 0.5 * v_peak * accel_time
    b = (tau > accel_time) & (tau <= accel_time + t_brake)
    y = (tau[b] - accel_time) / t_brake
    v[b] = 0.5 * v_peak * (1 + np.cos(np.pi * y))
    s[b] = s_a + 0.5 * v_peak * t_brake * (y + np.sin(np.pi * y) / np.pi)
    after = tau > accel_time + t_brake
    s[after] = s_a + 0.5 * v_peak * t_brake
    return s, v


def default_throw(
    speed: float = 0.8,
    yaw: float = 0.0,
    duration: float = 1.5,
    hold: float = 0.2,
    accel_time: float = 0.35,
    brake: float = 16.0,
    dt: float = 0.005,
) -> MotionPlan:
    """The default overhand throw (see module docstring).

    ``speed``: peak joint speed as a fraction of the 3.14 rad/s motor limit (0 < speed <= 1);
    ``yaw``: joint-1 angle in rad; ``duration``/``hold``/``accel_time``/``dt`` in s; ``brake`` in rad/s^2.
    """
    for name, v in (("speed", speed), ("yaw", yaw), ("duration", duration), ("hold", hold), ("accel_time", accel_time), ("brake", brake), ("dt", dt)):
        if not np.isfinite(v):
            raise ValueError(f"default_throw: {name} must be finite, got {v}")
    if not 0.0 < speed <= 1.0:
        raise ValueError(f"default_throw: speed must be in (0, 1] (fraction of the motor speed limit), got {speed}")
    if brake <= 0 or accel_time <= 0 or dt <= 0:
        raise ValueError("default_throw: brake, accel_time and dt must be positive")
    v_peak = speed * float(robot.VELOCITY_LIMITS[1])
    end = hold + accel_time + np.pi * v_peak / (2.0 * brake)
    if end > duration:
        raise ValueError(f"default_throw: the throw needs {end:.3f} s, longer than duration {duration} s")
    t = np.arange(0.0, duration + dt / 2, dt)
    t[-1] = duration
    s, v = _profile(t, hold, accel_time, v_peak, brake)
    start = START_POSE.copy()
    start[0] = yaw
    q = start + np.outer(s, SWING)
    qd = np.outer(v, SWING)
    return MotionPlan(t=t, q=q, qd=qd, meta={"generator": "default_throw", "speed": speed, "yaw": yaw, "brake": brake})


__all__ = ["default_throw", "START_POSE", "SWING"]
