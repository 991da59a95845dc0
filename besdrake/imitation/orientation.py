"""Unit-quaternion orientation DMP (Ude et al. 2014).

Transformation system (``y`` orientation quaternion, ``omega`` angular velocity in the world frame,
``tau`` execution time)::

    omega_dot = (alpha_y (beta_y 2 log(g * conj(y)) - tau omega) + f(z)) / tau**2
    y <- exp(h omega / 2) * y          (semi-implicit Euler, sub-steps h <= int_dt)

The phase, basis and forcing term are those of :mod:`.basis`; the goal angular velocity is zero
(as in Ude et al.). This is the orientation part of ``movement_primitives.dmp.CartesianDMP`` with
one deliberate difference: ``2 log`` is the logarithm on the 3-sphere (angle in ``[0, 2 pi]``), not
the one wrapped to ``[0, pi]``. Demonstrations are made sign-continuous before imitation, so the
goal's sign encodes the direction the demonstration turned, and rotations larger than pi between
start and goal are reproduced instead of being taken the short way round. For rotations below pi
the two agree.

Limitation (of the formulation, not of the integration): while the remaining rotation exceeds pi
the attractor is unstable across the geodesic (all long-way geodesics meet at the antipode), so
deviations from the demonstration grow there. Measured on a 1.2 s demonstration that starts at
rest: largest deviation 0.01 rad for a 1.5 pi turn, 0.13-0.3 rad for a 1.8 pi turn. The DMP starts
at rest; a demonstration that starts moving cannot be matched at its start.

Double cover: assigning ``start`` or ``goal`` keeps the sign nearest to the previous value (``q``
and ``-q`` are the same orientation; the choice is made continuous so that moving a goal never
flips the turning direction).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from besdrake.imitation import quaternion as quat
from besdrake.imitation._validation import DMPParameterError, demonstration, finite_array, positive_float
from besdrake.imitation.basis import RadialBasis, phase
from besdrake.imitation.dmp import DEFAULT_ALPHA_Y, DEFAULT_BETA_Y, DEFAULT_INT_DT, MAX_SUBSTEPS, _WeightedDMP, end_at_run_time, substeps


@dataclass
class OrientationTrajectory:
    """Orientation rollout: times (N,) s, quaternions (N, 4) (w, x, y, z), angular velocity (N, 3) rad/s.

    ``omega`` is the integrator's angular velocity (world frame) over the sub-step that ended at
    the sample, i.e. half a sub-step behind the orientation (unlike :class:`DMPTrajectory`, whose
    velocities are at the sample time; the nonlinear orientation update makes that conversion
    inexact, so it is not done here).
    """

    t: np.ndarray
    q: np.ndarray
    omega: np.ndarray


class QuaternionDMP(_WeightedDMP):
    """Orientation DMP on unit quaternions; ``fit``, ``open_loop``, ``step``, weights get/set."""

    #: Dimensions of the forcing term (angular, in the tangent space of the quaternions).
    n_dims = 3

    def __init__(
        self,
        n_weights_per_dim: int = 10,
        execution_time: float = 1.0,
        alpha_y: float | np.ndarray = DEFAULT_ALPHA_Y,
        beta_y: float | np.ndarray = DEFAULT_BETA_Y,
        int_dt: float = DEFAULT_INT_DT,
    ) -> None:
        self.basis = RadialBasis.with_count(int(n_weights_per_dim))
        self.alpha_y = alpha_y
        self.beta_y = beta_y
        self.int_dt = int_dt
        self.execution_time = execution_time
        self._start = np.array([1.0, 0.0, 0.0, 0.0])
        self._goal = np.array([1.0, 0.0, 0.0, 0.0])
        self.weights = np.zeros((3, self.n_weights_per_dim))

    @property
    def start(self) -> np.ndarray:
        """Start orientation (w, x, y, z)."""
        return self._start.copy()

    @start.setter
    def start(self, q: np.ndarray) -> None:
        q = quat.unit("start", q)
        self._start = q if np.dot(q, self._start) >= 0.0 else -q

    @property
    def goal(self) -> np.ndarray:
        """Goal orientation (w, x, y, z); its sign relative to ``start`` sets the turning direction."""
        return self._goal.copy()

    @goal.setter
    def goal(self, q: np.ndarray) -> None:
        q = quat.unit("goal", q)
        self._goal = q if np.dot(q, self._goal) >= 0.0 else -q

    def set_start_and_goal(self, start: np.ndarray, goal: np.ndarray) -> None:
        """Set both exactly as given (signs included), e.g. to choose the turning direction."""
        object.__setattr__(self, "_start", quat.unit("start", start))
        object.__setattr__(self, "_goal", quat.unit("goal", goal))

    def copy(self) -> "QuaternionDMP":
        """Independent copy."""
        return QuaternionDMP.from_dict(self.to_dict())

    # -- imitation ----------------------------------------------------------------------------
    def fit(self, t: np.ndarray, q: np.ndarray, regularization: float = 0.0) -> "QuaternionDMP":
        """Imitate orientations ``q`` (N, 4) at times ``t`` (N,) s; signs are made continuous first."""
        t, _ = demonstration(t, np.zeros((np.size(t), 1)))
        q = quat.make_continuous(quat.unit("demonstrated orientations", q))
        if q.shape != (t.size, 4):
            raise DMPParameterError(f"orientations must have shape ({t.size}, 4), got {q.shape}")
        if not (np.isfinite(regularization) and regularization >= 0.0):
            raise DMPParameterError(f"regularization must be finite and >= 0, got {regularization}")
        t = t - t[0]
        tau = float(t[-1])
        # Angular velocity: central differences inside, one-sided at the ends; zero at the goal.
        omega = np.empty((t.size, 3))
        omega[0] = quat.rotation_vector(quat.multiply(q[1], quat.conjugate(q[0]))) / (t[1] - t[0])
        omega[1:-1] = quat.rotation_vector(quat.multiply(q[2:], quat.conjugate(q[:-2]))) / (t[2:] - t[:-2])[:, None]
        omega[-1] = 0.0
        omega_dot = np.gradient(omega, axis=0) / np.gradient(t)[:, None]
        omega_dot[-1] = 0.0
        goal = q[-1]
        error = quat.rotation_vector(quat.multiply(goal, quat.conjugate(q)))
        forces = tau**2 * omega_dot - self.alpha_y * (self.beta_y * error - tau * omega)
        X = self.basis.features(phase(t, tau))
        if regularization > 0.0:
            X = np.vstack((X, math.sqrt(regularization) * np.eye(self.n_weights_per_dim)))
            forces = np.vstack((forces, np.zeros((self.n_weights_per_dim, 3))))
        self.weights = np.linalg.lstsq(X, forces, rcond=None)[0].T
        self.execution_time = tau
        self.set_start_and_goal(q[0], goal)
        return self

    # -- integration --------------------------------------------------------------------------
    def _integrate(self, t0: float, q: np.ndarray, omega: np.ndarray, h: float, n: int, every: int):
        """``n`` sub-steps of ``h`` from time ``t0``; returns states after every ``every``-th sub-step."""
        tau = self.execution_time
        forces = self.basis.features(phase(t0 + np.arange(1, n + 1) * h, tau)) @ self.weights.T
        ab = (self.alpha_y * self.beta_y).tolist()
        a_tau = (self.alpha_y * tau).tolist()
        inv_tau2 = 1.0 / tau**2
        gw, gx, gy, gz = self._goal.tolist()
        yw, yx, yy, yz = (float(c) for c in q)
        ox, oy, oz = (float(c) for c in omega)
        out_q, out_w = [], []
        for j, (fx, fy, fz) in enumerate(forces.tolist()):
            # e = 2 log(g * conj(y)) on the 3-sphere
            ew = gw * yw + gx * yx + gy * yy + gz * yz
            ex = yw * gx - gw * yx - (gy * yz - gz * yy)
            ey = yw * gy - gw * yy - (gz * yx - gx * yz)
            ez = yw * gz - gw * yz - (gx * yy - gy * yx)
            n_e = math.sqrt(ex * ex + ey * ey + ez * ez)
            if n_e > 1e-12:
                k = 2.0 * math.atan2(n_e, ew) / n_e
            else:
                k = 2.0 / ew if ew > 0.0 else 0.0
            ox += h * (ab[0] * k * ex - a_tau[0] * ox + fx) * inv_tau2
            oy += h * (ab[1] * k * ey - a_tau[1] * oy + fy) * inv_tau2
            oz += h * (ab[2] * k * ez - a_tau[2] * oz + fz) * inv_tau2
            # y <- exp(h omega / 2) * y
            rx, ry, rz = h * ox, h * oy, h * oz
            angle = math.sqrt(rx * rx + ry * ry + rz * rz)
            if angle > 1e-12:
                s = math.sin(0.5 * angle) / angle
                dw = math.cos(0.5 * angle)
            else:
                s, dw = 0.5, 1.0
            dx, dy, dz = s * rx, s * ry, s * rz
            yw, yx, yy, yz = (
                dw * yw - dx * yx - dy * yy - dz * yz,
                dw * yx + yw * dx + (dy * yz - dz * yy),
                dw * yy + yw * dy + (dz * yx - dx * yz),
                dw * yz + yw * dz + (dx * yy - dy * yx),
            )
            if (j + 1) % every == 0:
                out_q.append((yw, yx, yy, yz))
                out_w.append((ox, oy, oz))
        return np.array(out_q).reshape(-1, 4), np.array(out_w).reshape(-1, 3)

    def open_loop(self, dt: float = 0.01, run_time: float | None = None) -> OrientationTrajectory:
        """Roll out from ``start`` at rest, sampled every ``dt`` s until ``run_time`` (default: execution
        time); the last sample is at ``run_time`` exactly (see :meth:`DMP.open_loop`)."""
        dt = positive_float("dt", dt)
        run_time = self.execution_time if run_time is None else positive_float("run_time", run_time)
        n_sub = substeps(dt, self.int_dt)
        n_out = int(math.floor(run_time / dt + 1e-9)) + 1
        if (n_out - 1) * n_sub > MAX_SUBSTEPS:
            raise DMPParameterError(f"rollout of {run_time:g} s needs more than {MAX_SUBSTEPS} sub-steps")
        q, w = self._integrate(0.0, self._start, np.zeros(3), dt / n_sub, (n_out - 1) * n_sub, n_sub)
        t_out, q_out, w_out = np.arange(n_out) * dt, np.vstack((self._start, q)), np.vstack((np.zeros(3), w))
        return OrientationTrajectory(*end_at_run_time(self.step, t_out, q_out, w_out, run_time, dt))

    def step(self, t: float, q: np.ndarray, omega: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """One step of ``dt`` s from orientation ``q`` and angular velocity ``omega`` at DMP time ``t``."""
        dt = positive_float("dt", dt)
        q = quat.unit("q", q)
        omega = finite_array("omega", omega, (3,))
        n_sub = substeps(dt, self.int_dt)
        q_new, w_new = self._integrate(float(t), q, omega, dt / n_sub, n_sub, n_sub)
        return q_new[-1], w_new[-1]

    # -- persistence --------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {
            "type": "QuaternionDMP",
            **self._meta_dict(),
            "start": self._start.tolist(),
            "goal": self._goal.tolist(),
            "weights": self.weights.tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "QuaternionDMP":
        try:
            dmp = cls(
                data["n_weights_per_dim"], data["execution_time"], data["alpha_y"], data["beta_y"],
                data.get("int_dt", DEFAULT_INT_DT),
            )
            dmp.set_start_and_goal(data["start"], data["goal"])
            dmp.weights = data["weights"]
        except KeyError as err:
            raise DMPParameterError(f"QuaternionDMP description lacks the field {err.args[0]!r}") from err
        return dmp
