"""Dynamical movement primitive with a goal velocity (Muelling et al. 2011/2013) in a vector space.

Transformation system (``tau`` execution time, ``z`` phase, see :mod:`.basis`)::

    ydd = (alpha_y (beta_y (g(t) - y) + tau (gd(t) - yd)) + f(z)) / tau**2 + gdd(t)

``g(t)`` is a moving goal: the quintic polynomial from (start, start velocity, start acceleration)
at ``t = 0`` to (goal, goal velocity, goal acceleration) at ``t = tau``; after ``tau`` it stays at the
goal with zero velocity. With ``f = 0`` the DMP follows ``g`` exactly, so it arrives at the goal
with the goal velocity at ``t = tau``; changing ``tau`` rescales the movement in time and keeps
the final velocity. Integration is semi-implicit Euler (velocity first, then position) with
uniform sub-steps of at most ``int_dt``; the acceleration of a sub-step is evaluated at its end
time. This is the formulation of ``movement_primitives.dmp.DMPWithFinalVelocity`` (our test
oracle). Where we deliberately differ (tested as properties, not against the oracle):

* a step ``dt`` that is not a multiple of ``int_dt`` is split into equal sub-steps
  (``dt / ceil(dt / int_dt)``) instead of ``int_dt`` steps plus a remainder, so that the
  integration is uniform and the open-loop rollout can run as a linear recursive filter;
* imitation measures time from the first sample, so demonstrations need not start at t = 0;
* the moving goal switches to rest after ``tau`` with a tolerance of 1e-9 s (the oracle's
  switch depends on floating-point rounding of its accumulated time at the last step);
* a rollout ends exactly at its run time (default: ``tau``, where the goal velocity is reached):
  when that is not a multiple of ``dt`` the last sample interval is shorter (the oracle samples
  ``numpy.arange(0, run_time + dt, dt)``, which may end before or after it).

Velocities: in semi-implicit Euler the integrator's velocity is the velocity over the sub-step
just finished, half a sub-step behind the position. Rollouts and :meth:`DMP.step` report instead
the velocity at the sample time: the second-order backward difference of the positions
(``(3 y[j] - 4 y[j-1] + y[j-2]) / 2h``; at ``t = 0``: ``start_velocity + h/2 * initial
acceleration``, the velocity of the Euler path's smooth interpolant). Positions and these
velocities are consistent to second order, so a cubic Hermite interpolation of the samples
(``MotionPlan``, Drake ``CubicHermite``) has the DMP's accelerations; with the lagging integrator
velocity it would overshoot them by up to 2.5x (measured: 29 vs 12 rad/s^2 at 2 ms samples).

The open-loop rollout is vectorised: the forcing term and moving goal are evaluated for all
sub-steps at once and the linear recursion runs in :func:`scipy.signal.lfilter`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.signal import lfilter

from besdrake.imitation._validation import (
    DMPParameterError,
    demonstration,
    finite_array,
    positive_float,
)
from besdrake.imitation.basis import RadialBasis, phase

#: Default gains (critically damped: beta_y = alpha_y / 4).
DEFAULT_ALPHA_Y = 25.0
DEFAULT_BETA_Y = 6.25
#: Default largest integration sub-step in s.
DEFAULT_INT_DT = 0.001
#: Tolerance (s) when deciding whether a time lies after the execution time.
TIME_TOLERANCE = 1e-9
#: A rollout whose run time exceeds its last multiple of ``dt`` by more than this (s) gets a final,
#: shorter step so that it ends exactly at the run time.
END_TOLERANCE = 1e-7
#: That final step, where shorter than this fraction of ``dt``, is merged into the step before it (the sample before
#: it dropped, the end state integrated over ``dt + remainder`` from the sample before that): a robot's controller
#: cannot follow knots microseconds apart (a safety gate refuses knots closer than the robot's control period, e.g.
#: 0.1 ms), and refined execution times fell into that window for 20 of 400 plans at dt = 2 ms (issue 27, session 19).
MIN_LAST_STEP_FRACTION = 0.1
#: Largest number of integration sub-steps of one rollout (a guard against absurd run times).
MAX_SUBSTEPS = 20_000_000


def end_at_run_time(step, t_out: np.ndarray, y_out: np.ndarray, yd_out: np.ndarray, run_time: float, dt: float):
    """End a rollout sampled every ``dt`` exactly at ``run_time``: one shorter last step, or, where that step would be
    shorter than :data:`MIN_LAST_STEP_FRACTION` of ``dt``, the last sample moved to ``run_time`` (integrated over
    ``dt + remainder`` from the sample before it). ``step(t, y, yd, dt)`` integrates one step."""
    remainder = run_time - t_out[-1]
    if remainder <= END_TOLERANCE:
        return t_out, y_out, yd_out
    if remainder < MIN_LAST_STEP_FRACTION * dt and len(t_out) > 1:
        y_end, yd_end = step(t_out[-2], y_out[-2], yd_out[-2], dt + remainder)
        t_out, y_out, yd_out = t_out.copy(), y_out.copy(), yd_out.copy()
        t_out[-1], y_out[-1], yd_out[-1] = run_time, y_end, yd_end
        return t_out, y_out, yd_out
    y_end, yd_end = step(t_out[-1], y_out[-1], yd_out[-1], remainder)
    return np.append(t_out, run_time), np.vstack((y_out, y_end)), np.vstack((yd_out, yd_end))


@dataclass
class DMPTrajectory:
    """A DMP rollout: times (N,) in s, positions (N, n_dims) and velocities (N, n_dims)."""

    t: np.ndarray
    y: np.ndarray
    yd: np.ndarray


def quintic_coefficients(
    duration: float,
    y0: np.ndarray,
    yd0: np.ndarray,
    ydd0: np.ndarray,
    y1: np.ndarray,
    yd1: np.ndarray,
    ydd1: np.ndarray,
) -> np.ndarray:
    """Coefficients ``(6, n_dims)`` of ``p(t) = sum_k c_k t**k`` matching both boundary states."""
    T = duration
    M = np.array(
        [
            [1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 2.0, 0.0, 0.0, 0.0],
            [1.0, T, T**2, T**3, T**4, T**5],
            [0.0, 1.0, 2 * T, 3 * T**2, 4 * T**3, 5 * T**4],
            [0.0, 0.0, 2.0, 6 * T, 12 * T**2, 20 * T**3],
        ]
    )
    return np.linalg.solve(M, np.vstack((y0, yd0, ydd0, y1, yd1, ydd1)))


def moving_goal(
    t: np.ndarray, coefficients: np.ndarray, goal: np.ndarray, execution_time: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Moving goal position, velocity, acceleration ``(len(t), n_dims)``; at rest on the goal after ``tau``."""
    t = np.atleast_1d(np.asarray(t, dtype=float))
    powers = t[:, None] ** np.arange(6)
    k = np.arange(6)
    g = powers @ coefficients
    gd = (powers[:, :5] * k[1:]) @ coefficients[1:]
    gdd = (powers[:, :4] * (k[2:] * k[1:5])) @ coefficients[2:]
    after = t > execution_time + TIME_TOLERANCE
    if np.any(after):
        g[after] = goal
        gd[after] = 0.0
        gdd[after] = 0.0
    return g, gd, gdd


def substeps(dt: float, int_dt: float) -> int:
    """Number of equal integration sub-steps (each <= ``int_dt``) in one step of ``dt``."""
    return max(1, math.ceil(dt / int_dt - 1e-9))


class _WeightedDMP:
    """What the DMPs of this package share (base class): forcing-term weights ``(n_dims, n_weights_per_dim)``
    on a radial basis and the meta-parameters ``execution_time``, ``int_dt``, ``alpha_y``, ``beta_y``,
    validated on assignment."""

    n_dims: int
    basis: RadialBasis
    weights: np.ndarray
    alpha_y: np.ndarray
    beta_y: np.ndarray
    int_dt: float
    execution_time: float

    def __setattr__(self, name: str, value: Any) -> None:
        if name in ("execution_time", "int_dt"):
            value = positive_float(name, value)
        elif name in ("alpha_y", "beta_y"):
            value = finite_array(name, value, (self.n_dims,))
            if np.any(value <= 0.0):
                raise DMPParameterError(f"{name} must be > 0, got {value}")
        elif name == "weights":
            value = finite_array("weights", value, (self.n_dims, self.n_weights_per_dim))
        object.__setattr__(self, name, value)

    @property
    def n_weights_per_dim(self) -> int:
        return self.basis.n_weights

    @property
    def n_weights(self) -> int:
        """Total number of forcing-term weights."""
        return self.n_dims * self.n_weights_per_dim

    def get_weights(self) -> np.ndarray:
        """Flat copy of the weights, dimension-major (all weights of dim 0 first)."""
        return self.weights.ravel().copy()

    def set_weights(self, weights: np.ndarray) -> None:
        """Set the weights from a flat vector of length ``n_weights``."""
        flat = finite_array("weights", weights, (self.n_weights,))
        self.weights = flat.reshape(self.n_dims, self.n_weights_per_dim)

    def _meta_dict(self) -> dict[str, Any]:
        """The shared part of ``to_dict`` (SI units)."""
        return {
            "n_weights_per_dim": self.n_weights_per_dim,
            "alpha_y": self.alpha_y.tolist(),
            "beta_y": self.beta_y.tolist(),
            "int_dt": self.int_dt,
            "execution_time": self.execution_time,
        }


class DMP(_WeightedDMP):
    """Joint-space (or any vector-space) DMP with start, goal, goal velocity and execution time.

    Meta-parameters are attributes (validated on assignment): ``start``, ``goal``,
    ``goal_velocity``, ``start_velocity``, ``start_acceleration``, ``goal_acceleration`` (units of
    the positions: rad, rad/s, rad/s^2 for joints), ``execution_time`` (s) and ``weights``
    ``(n_dims, n_weights_per_dim)``. ``fit`` imitates a demonstration.
    """

    def __init__(
        self,
        n_dims: int,
        n_weights_per_dim: int = 10,
        execution_time: float = 1.0,
        alpha_y: float | np.ndarray = DEFAULT_ALPHA_Y,
        beta_y: float | np.ndarray = DEFAULT_BETA_Y,
        int_dt: float = DEFAULT_INT_DT,
    ) -> None:
        if int(n_dims) != n_dims or n_dims < 1:
            raise DMPParameterError(f"n_dims must be a positive integer, got {n_dims}")
        self.n_dims = int(n_dims)
        self.basis = RadialBasis.with_count(int(n_weights_per_dim))
        self.alpha_y = alpha_y
        self.beta_y = beta_y
        self.int_dt = int_dt
        self.execution_time = execution_time
        zeros = np.zeros(self.n_dims)
        self.start = zeros
        self.goal = zeros
        self.start_velocity = zeros
        self.start_acceleration = zeros
        self.goal_velocity = zeros
        self.goal_acceleration = zeros
        self.weights = np.zeros((self.n_dims, self.n_weights_per_dim))

    # -- validated meta-parameters (the shared ones in _WeightedDMP) ----------------------------
    def __setattr__(self, name: str, value: Any) -> None:
        if name in _VECTOR_FIELDS:
            value = finite_array(name, value, (self.n_dims,))
        super().__setattr__(name, value)

    def copy(self) -> "DMP":
        """Independent copy."""
        new = object.__new__(DMP)
        for name, value in self.__dict__.items():
            object.__setattr__(new, name, value.copy() if isinstance(value, np.ndarray) else value)
        return new

    # -- imitation ----------------------------------------------------------------------------
    def fit(self, t: np.ndarray, y: np.ndarray, regularization: float = 0.0,
            start_velocity: np.ndarray | None = None) -> "DMP":
        """Imitate a demonstration: times ``(N,)`` in s, positions ``(N, n_dims)``.

        Sets start and goal to the first and last sample, the goal velocity and acceleration to
        backward differences at the last sample (start velocity and acceleration to zero, or the
        start velocity to ``start_velocity``: a segment that continues one ending in motion), the
        execution time to the demonstration's duration, and the weights by (ridge) regression of
        the forcing term that reproduces the demonstrated accelerations.
        """
        t, y = demonstration(t, y, self.n_dims)
        if not (np.isfinite(regularization) and regularization >= 0.0):
            raise DMPParameterError(f"regularization must be finite and >= 0, got {regularization}")
        v0 = np.zeros(self.n_dims) if start_velocity is None else finite_array("start_velocity", start_velocity, (self.n_dims,))
        t = t - t[0]
        tau = float(t[-1])
        dts = np.diff(t)[:, None]
        yd = np.zeros_like(y)
        yd[1:] = np.diff(y, axis=0) / dts
        ydd = np.zeros_like(y)
        ydd[1:] = np.diff(yd, axis=0) / dts
        zeros = np.zeros(self.n_dims)
        coefficients = quintic_coefficients(tau, y[0], v0, zeros, y[-1], yd[-1], ydd[-1])
        g, gd, gdd = moving_goal(t, coefficients, y[-1], tau)
        a, b = self.alpha_y, self.beta_y
        forces = tau**2 * ydd - a * (b * (g - y) + tau * (gd - yd)) - tau**2 * gdd
        X = self.basis.features(phase(t, tau))
        if regularization > 0.0:
            X = np.vstack((X, math.sqrt(regularization) * np.eye(self.n_weights_per_dim)))
            forces = np.vstack((forces, np.zeros((self.n_weights_per_dim, self.n_dims))))
        weights = np.linalg.lstsq(X, forces, rcond=None)[0].T
        self.execution_time = tau
        self.start, self.goal = y[0], y[-1]
        self.start_velocity, self.start_acceleration = v0, zeros
        self.goal_velocity, self.goal_acceleration = yd[-1], ydd[-1]
        self.weights = weights
        return self

    # -- integration --------------------------------------------------------------------------
    def _coefficients(self, goal: np.ndarray) -> np.ndarray:
        return quintic_coefficients(
            self.execution_time,
            self.start,
            self.start_velocity,
            self.start_acceleration,
            goal,
            self.goal_velocity,
            self.goal_acceleration,
        )

    def _drive(self, t: np.ndarray, coefficients: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """State-independent part ``u(t)`` of the acceleration, ``(len(t), n_dims)``."""
        tau = self.execution_time
        g, gd, gdd = moving_goal(t, coefficients, goal, tau)
        f = self.basis.features(phase(t, tau)) @ self.weights.T
        return (self.alpha_y * (self.beta_y * g + tau * gd) + f) / tau**2 + gdd

    def open_loop(self, dt: float = 0.01, run_time: float | None = None) -> DMPTrajectory:
        """Roll the DMP out from its start state, sampled every ``dt`` s up to ``run_time``
        (default: the execution time; it may be shorter or longer). The last sample is at
        ``run_time`` exactly (a shorter last interval if ``run_time`` is not a multiple of ``dt``).
        Velocities are sample-time velocities (see the module docstring)."""
        dt = positive_float("dt", dt)
        run_time = self.execution_time if run_time is None else positive_float("run_time", run_time)
        n_sub = substeps(dt, self.int_dt)
        h = dt / n_sub
        n_out = int(math.floor(run_time / dt + 1e-9)) + 1
        n_int = (n_out - 1) * n_sub
        if n_int > MAX_SUBSTEPS:
            raise DMPParameterError(
                f"rollout of {run_time:g} s at int_dt {self.int_dt:g} s needs {n_int} sub-steps (limit {MAX_SUBSTEPS})"
            )
        tau = self.execution_time
        # One sub-step beyond the last sample, for the velocity there.
        t_int = np.arange(1, n_int + 2) * h
        u = self._drive(t_int, self._coefficients(self.goal), self.goal)
        # Semi-implicit Euler as the linear recursion y[j] = c1 y[j-1] - c2 y[j-2] + h^2 u[j],
        # started from y[-1] = y[0] - h * start_velocity.
        damping = self.alpha_y / tau
        stiffness = self.alpha_y * self.beta_y / tau**2
        c1 = 2.0 - h * damping - h * h * stiffness
        c2 = 1.0 - h * damping
        y = np.empty((n_int + 3, self.n_dims))  # y[-1], y[0], ..., y[n_int + 1]
        y[0] = self.start - h * self.start_velocity
        y[1] = self.start
        zi = np.vstack((c1 * y[1] - c2 * y[0], -c2 * y[1]))
        if np.all(c1 == c1[0]) and np.all(c2 == c2[0]):
            y[2:] = lfilter([h * h], [1.0, -c1[0], c2[0]], u, axis=0, zi=zi)[0]
        else:
            for d in range(self.n_dims):
                y[2:, d] = lfilter([h * h], [1.0, -c1[d], c2[d]], u[:, d], zi=zi[:, d])[0]
        nodes = np.arange(0, n_int + 1, n_sub) + 1  # array index of sample k is k * n_sub + 1
        t_out = np.arange(n_out) * dt
        y_out = y[nodes]
        yd_out = np.empty_like(y_out)
        # Sample-time velocity: at t = 0 the mean over the first sub-steps' velocities (y[-1] is
        # defined by the start velocity), later the second-order backward difference (it does not
        # look across the switch of the moving goal at tau).
        yd_out[0] = (y[2] - y[0]) / (2.0 * h)
        later = nodes[1:]
        yd_out[1:] = (3.0 * y[later] - 4.0 * y[later - 1] + y[later - 2]) / (2.0 * h)
        return DMPTrajectory(*end_at_run_time(self.step, t_out, y_out, yd_out, run_time, dt))

    def step(
        self, t: float, y: np.ndarray, yd: np.ndarray, dt: float, goal: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Integrate one step of ``dt`` s from position ``y`` and sample-time velocity ``yd`` at DMP
        time ``t`` (s since the start); returns the new ``(y, yd)``. From a rollout's sample it
        reproduces the rollout's next sample.

        Closed-loop use: pass the measured (or last commanded) state. ``goal`` replaces the goal for
        this step only (online adaptation; the moving goal is recomputed).
        """
        goal = self.goal if goal is None else finite_array("goal", goal, (self.n_dims,))
        dt = positive_float("dt", dt)
        y = finite_array("y", y, (self.n_dims,)).copy()
        v = finite_array("yd", yd, (self.n_dims,))
        n_sub = substeps(dt, self.int_dt)
        h = dt / n_sub
        u = self._drive(float(t) + np.arange(0, n_sub + 1) * h, self._coefficients(goal), goal)
        tau = self.execution_time
        damping = self.alpha_y / tau
        stiffness = self.alpha_y * self.beta_y / tau**2
        # Sample-time velocity v -> the integrator's velocity yd over the last sub-step, inverting
        # how open_loop reports v: at the start v = yd + h/2 * (acceleration of the next sub-step),
        # later v = yd + h/2 * (acceleration of the previous sub-step, which ended at t).
        if float(t) < 0.5 * h:
            yd = (v - 0.5 * h * (u[1] - stiffness * y)) / (1.0 - 0.5 * h * damping)
        else:
            scale = 1.0 - h * damping
            yd = (v - 0.5 * h * (u[0] - stiffness * y) / scale) / (1.0 + 0.5 * h * (h * stiffness - damping) / scale)
        yd_before = yd
        for j in range(1, n_sub + 1):
            yd_before = yd
            yd = yd + h * (u[j] - stiffness * y - damping * yd)
            y += h * yd
        return y, yd + 0.5 * (yd - yd_before)

    def start_state(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Position and sample-time velocity at ``t = 0`` for steps of ``dt`` (``open_loop(dt)``'s first sample)."""
        traj = self.open_loop(dt, run_time=positive_float("dt", dt))
        return traj.y[0], traj.yd[0]

    # -- persistence --------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable description (SI units)."""
        return {
            "type": "DMP",
            "n_dims": self.n_dims,
            **self._meta_dict(),
            **{name: getattr(self, name).tolist() for name in _VECTOR_FIELDS},
            "weights": self.weights.tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "DMP":
        """Inverse of :meth:`to_dict`; raises :class:`DMPParameterError` on missing or bad fields."""
        try:
            if data.get("type", "DMP") != "DMP":
                raise DMPParameterError(f"expected a DMP description, got type {data.get('type')!r}")
            dmp = cls(
                data["n_dims"],
                data["n_weights_per_dim"],
                data["execution_time"],
                data["alpha_y"],
                data["beta_y"],
                data.get("int_dt", DEFAULT_INT_DT),
            )
            for name in _VECTOR_FIELDS:
                setattr(dmp, name, data[name])
            dmp.weights = data["weights"]
        except KeyError as err:
            raise DMPParameterError(f"DMP description lacks the field {err.args[0]!r}") from err
        return dmp

    def save(self, path: str | Path) -> None:
        """Write the DMP as JSON (:func:`besdrake.imitation.io.save_dmp`)."""
        from besdrake.imitation.io import save_dmp  # io imports this module

        save_dmp(self, path)

    @classmethod
    def load(cls, path: str | Path) -> "DMP":
        """Read a DMP written by :meth:`save`; :class:`DMPParameterError` for a missing or corrupt file."""
        from besdrake.imitation.io import _read_dmp_json  # io imports this module

        return cls.from_dict(_read_dmp_json(path))


_VECTOR_FIELDS = (
    "start",
    "goal",
    "start_velocity",
    "start_acceleration",
    "goal_velocity",
    "goal_acceleration",
)

__all__ = ["DMP", "DMPTrajectory", "moving_goal", "quintic_coefficients", "substeps"]
