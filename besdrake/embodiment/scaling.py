"""Spatial and temporal scaling of a joint trajectory to a robot's capabilities.

Temporal scaling (paper sections 2.3.2 and 3.1.4): a human movement is faster than a robot's motors
allow, so the movement is slowed down uniformly. Stretching time by ``k`` divides joint velocities
by ``k`` and accelerations by ``k**2``; the smallest admissible ``k`` is

    k = max(1, max|qd| / v_max, sqrt(max|qdd| / a_max), T_min / T)

with ``v_max`` and ``a_max`` the robot file's joint limits (times a safety factor) and
the paper's minimum execution time ``T_min`` = 0.95 s. A uniform stretch keeps the path and the
relative timing of the demonstration, which a DMP's execution time expresses exactly.

The time-optimal bound along the same joint path comes from Drake's ``Toppra`` (velocity and
acceleration limits per joint): it says how much faster a non-uniform retiming could be, and is
reported beside the uniform scaling.

Spatial scaling: the DMP's start and goal are meta-parameters; :func:`clip_to_limits` keeps them
inside the joint limits with a margin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from besdrake.robot import JointLimits
from besdrake.imitation.policy import MIN_IMITATED_EXECUTION_TIME


@dataclass
class TemporalScaling:
    """Result of temporal scaling."""

    factor: float  # k >= 1: new duration = k * demonstrated duration (before T_min)
    duration: float  # s, the scaled execution time
    demo_duration: float  # s
    peak_velocity_demo: np.ndarray  # (6,) rad/s at the demonstrated speed
    peak_acceleration_demo: np.ndarray  # (6,) rad/s^2
    limiting: str  # "velocity", "acceleration", "minimum execution time" or "none"
    toppra_duration: float | None  # s, time-optimal duration along the path (None if Toppra failed)


def derivatives(t: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Velocities and accelerations of samples ``q`` (n, d) by second-order finite differences.

    Interpolating splines ring at a DMP's start-up transient and would overstate the peak
    acceleration; differences of dense samples do not.
    """
    if len(t) < 3:
        raise ValueError(f"need at least 3 samples for derivatives, got {len(t)}")
    qd = np.gradient(q, t, axis=0)
    return qd, np.gradient(qd, t, axis=0)


def temporal_scaling(
    t: np.ndarray,
    q: np.ndarray,
    limits: JointLimits,
    safety: float = 0.9,
    min_duration: float = MIN_IMITATED_EXECUTION_TIME,
    plant=None,
) -> TemporalScaling:
    """Smallest uniform time stretch that keeps ``safety`` x the robot's ``limits`` (see module docstring);
    with ``plant`` (the robot welded at its base) also Toppra's time-optimal bound."""
    velocity_limits, acceleration_limits = limits.velocity, limits.acceleration
    qd, qdd = derivatives(t, q)
    v = np.abs(qd).max(axis=0)
    a = np.abs(qdd).max(axis=0)
    T = float(t[-1] - t[0])
    candidates = {
        "none": 1.0,
        "velocity": float(np.max(v / (safety * velocity_limits))),
        "acceleration": float(np.sqrt(np.max(a / (safety * acceleration_limits)))),
        "minimum execution time": min_duration / T if T > 0 else np.inf,
    }
    limiting = max(candidates, key=candidates.get)
    k = max(candidates.values())
    bound = toppra_duration(t, q, velocity_limits, acceleration_limits, plant=plant) if plant is not None else None
    return TemporalScaling(
        factor=float(k), duration=float(k * T), demo_duration=T, peak_velocity_demo=v,
        peak_acceleration_demo=a, limiting=limiting, toppra_duration=bound,
    )


def toppra_duration(
    t: np.ndarray,
    q: np.ndarray,
    velocity_limits: np.ndarray,
    acceleration_limits: np.ndarray,
    plant,
    gridpoints: int = 200,
) -> float | None:
    """Time-optimal duration of the joint path ``q(t)`` under per-joint limits (Drake's Toppra) for ``plant``,
    the robot welded at its base; None when Toppra fails."""
    from pydrake.multibody.optimization import Toppra
    from pydrake.trajectories import PiecewisePolynomial

    s = (t - t[0]) / (t[-1] - t[0])
    n = q.shape[1]
    path = PiecewisePolynomial.CubicWithContinuousSecondDerivatives(s, q.T, np.zeros(n), np.zeros(n))
    grid = Toppra.CalcGridPoints(path, _GridOptions(gridpoints))
    top = Toppra(path, plant, grid)
    top.AddJointVelocityLimit(-velocity_limits, velocity_limits)
    top.AddJointAccelerationLimit(-acceleration_limits, acceleration_limits)
    result = top.SolvePathParameterization()
    if result is None:
        return None
    return float(result.end_time() - result.start_time())


def toppra_retime(
    t: np.ndarray,
    q: np.ndarray,
    limits: JointLimits,
    model,
    safety: float = 0.9,
    dt: float = 0.02,
    gridpoints: int = 400,
    max_duration: float = 600.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The joint path ``q(t)`` (n, arm joints) retimed as fast as ``safety`` x the velocity and acceleration limits
    allow along it (Drake's Toppra on ``model``, a :class:`~besdrake.embodiment.kinematics.KinematicModel` of the
    robot welded at its base; a gripper's joints held where ``model.positions`` puts them), sampled every ``dt``
    s from 0: ``(t_new, q_new, t_path)`` (``t_path``: the path's own time ``t`` reached at each ``t_new``, to map
    events along the path), or None when Toppra fails or finds no retiming shorter than ``max_duration`` s (one
    that crawls through a near-singular stretch would otherwise be sampled into millions of rows)."""
    from pydrake.multibody.optimization import Toppra
    from pydrake.trajectories import PiecewisePolynomial

    s = (t - t[0]) / (t[-1] - t[0])
    full = np.array([model.positions(qi) for qi in q])
    n_all, arm = full.shape[1], model.arm_indices
    path = PiecewisePolynomial.CubicWithContinuousSecondDerivatives(s, full.T, np.zeros(n_all), np.zeros(n_all))
    top = Toppra(path, model.plant, Toppra.CalcGridPoints(path, _GridOptions(gridpoints)))
    vel, acc = np.full(n_all, 1e3), np.full(n_all, 1e3)  # a gripper's joints do not move along the path
    vel[arm], acc[arm] = safety * limits.velocity, safety * limits.acceleration
    top.AddJointVelocityLimit(-vel, vel)
    top.AddJointAccelerationLimit(-acc, acc)
    s_of_t = _quietly(top.SolvePathParameterization)
    if s_of_t is None:
        return None
    t0, T = s_of_t.start_time(), float(s_of_t.end_time() - s_of_t.start_time())
    if not np.isfinite(T) or T <= 0 or T > max_duration:
        return None
    t_new = np.linspace(0.0, T, max(3, int(np.ceil(T / dt)) + 1))
    s_new = np.clip(s_of_t.vector_values(list(t0 + t_new))[0], 0.0, 1.0)
    return t_new, path.vector_values(list(s_new))[arm].T, t[0] + s_new * (t[-1] - t[0])


def local_retime(t: np.ndarray, q: np.ndarray, limits: JointLimits, safety: float = 0.9, window: int = 5,
                 min_factor: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """A robust fallback of :func:`toppra_retime`: each sample interval of ``q(t)`` stretched by its own factor, the
    largest that its finite-difference velocity (and the acceleration at its ends) needs under ``safety`` x the limits
    (at least ``min_factor``), smoothed by a running maximum over ``window`` intervals each side. Returns ``(t_new,
    t)``: the new times of the same samples and the path's own times."""
    dt = np.diff(t)
    v = np.abs(np.diff(q, axis=0)) / dt[:, None] / (safety * limits.velocity)
    k = v.max(axis=1)
    if len(t) > 2:
        a = np.abs(np.diff(q, 2, axis=0)) / (0.5 * (dt[1:] + dt[:-1]) ** 2)[:, None] / (safety * limits.acceleration)
        ka = np.sqrt(a.max(axis=1))
        k = np.maximum(k, np.maximum(np.concatenate([ka, [0.0]]), np.concatenate([[0.0], ka])))
    k = np.maximum(k, min_factor)
    padded = np.concatenate([np.full(window, k[0]), k, np.full(window, k[-1])])
    k = np.array([padded[i : i + 2 * window + 1].max() for i in range(len(k))])
    return np.concatenate([[0.0], np.cumsum(k * dt)]), t


def _quietly(solve):
    """``solve()`` with Drake's log held back below CRITICAL: Toppra logs an ERROR line for a path it cannot retime,
    which the caller handles (it returns None here and the planner falls back); the user need not see it."""
    import logging

    log = logging.getLogger("drake")
    level = log.level
    log.setLevel(logging.CRITICAL)
    try:
        return solve()
    finally:
        log.setLevel(level)


def _GridOptions(n: int):
    from pydrake.multibody.optimization import CalcGridPointsOptions

    opts = CalcGridPointsOptions()
    opts.min_points = n
    return opts


def ease_in(t: np.ndarray, q: np.ndarray, duration: float) -> tuple[np.ndarray, np.ndarray]:
    """Prepend a constant-acceleration run-up so the trajectory starts at rest.

    A demonstrated segment starts where the previous sub-movement fades out, so the hand is
    still moving; a DMP (and the robot, holding its load) starts at rest, and the velocity jump
    would show up as a large acceleration in the first milliseconds. The run-up of ``duration``
    seconds reaches the segment's initial velocity ``v0`` with acceleration ``v0 / duration``
    and starts ``v0 * duration / 2`` behind the first sample. Returns times starting at 0.
    """
    if duration <= 0:
        return t - t[0], q
    dt = float(np.median(np.diff(t)))
    v0 = (q[1] - q[0]) / (t[1] - t[0])
    n = max(2, int(round(duration / dt)))
    tau = np.linspace(0.0, duration, n + 1)[:-1]
    run_up = q[0] - v0 * duration / 2.0 + 0.5 * (v0 / duration) * tau[:, None] ** 2
    return np.concatenate([tau, t - t[0] + duration]), np.vstack([run_up, q])


def clip_to_limits(q: np.ndarray, limits: JointLimits, margin: float = 0.05) -> np.ndarray:
    """Joint positions clipped into the position limits shrunk by ``margin`` rad."""
    return limits.clip(q, margin)
