"""Free flight of the ball after release, from its state at release to touchdown on the floor.

Once the ball has left the scoop for good nothing but gravity (and, with the ``air_drag`` effect, air)
acts on it, so the Drake simulation stops and the flight is computed here: in closed form (a parabola)
without drag, by a tight-tolerance ODE solve (scipy ``solve_ivp``, DOP853, event at touchdown) with
quadratic drag. Touchdown is the first instant the ball *touches* the floor: centre height = radius.
Spin (Magnus force) is not modelled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GRAVITY = 9.81  # m/s^2, Drake's default gravity field magnitude


@dataclass
class Flight:
    """Result of a flight: touchdown time (s after release), position and velocity there, sampled path."""

    duration: float
    touchdown_position: np.ndarray
    touchdown_velocity: np.ndarray
    t: np.ndarray
    path: np.ndarray


def fly(
    p0: np.ndarray,
    v0: np.ndarray,
    radius: float,
    mass: float = 0.05,
    drag_coefficient: float = 0.0,
    air_density: float = 1.2,
    wind: np.ndarray | None = None,
    gravity: float = GRAVITY,
    n_samples: int = 60,
    max_time: float = 10.0,
) -> Flight:
    """Fly a ball from ``p0`` (m) with ``v0`` (m/s) until its centre is ``radius`` above z = 0."""
    p0 = np.asarray(p0, dtype=float)
    v0 = np.asarray(v0, dtype=float)
    wind = np.zeros(3) if wind is None else np.asarray(wind, dtype=float)
    g = np.array([0.0, 0.0, -gravity])
    h0 = p0[2] - radius
    if h0 <= 0.0:
        return Flight(0.0, p0.copy(), v0.copy(), np.zeros(1), p0[None, :].copy())
    if drag_coefficient == 0.0:
        vz = v0[2]
        T = (vz + np.sqrt(vz * vz + 2.0 * gravity * h0)) / gravity
        ts = np.linspace(0.0, T, n_samples)
        path = p0 + np.outer(ts, v0) + 0.5 * np.outer(ts * ts, g)
        path[-1, 2] = radius
        return Flight(float(T), path[-1].copy(), v0 + g * T, ts, path)

    from scipy.integrate import solve_ivp

    k = 0.5 * air_density * drag_coefficient * np.pi * radius**2 / mass

    def rhs(_t, y):
        v_rel = y[3:] - wind
        return np.concatenate([y[3:], g - k * np.linalg.norm(v_rel) * v_rel])

    def ground(_t, y):
        return y[2] - radius

    ground.terminal = True
    ground.direction = -1
    sol = solve_ivp(rhs, (0.0, max_time), np.concatenate([p0, v0]), method="DOP853", events=ground, rtol=1e-10, atol=1e-12, dense_output=True)
    if sol.t_events[0].size == 0:
        raise RuntimeError("ball did not reach the floor within max_time")
    T = float(sol.t_events[0][0])
    ts = np.linspace(0.0, T, n_samples)
    ys = sol.sol(ts).T
    yT = sol.y_events[0][0]
    ys[-1] = yT
    return Flight(T, yT[:3].copy(), yT[3:].copy(), ts, ys[:, :3])
