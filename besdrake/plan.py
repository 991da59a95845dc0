"""Joint-space motion plans: the currency between the learning stages and the simulation.

A :class:`MotionPlan` is a sampled joint trajectory of a robot's arm: times ``t`` (N,) in s starting
at 0, positions ``q`` (N, n) in rad and optionally velocities ``qd`` (N, n) in rad/s, for the robot's n
arm joints (their names travel with the plan when known). DMPs and inverse kinematics produce plans;
:class:`besdrake.sim.Rollout` executes them. Limits are checked against a robot's
:class:`~besdrake.robot.JointLimits`.

Between samples the plan is a cubic Hermite through ``(q, qd)``; when ``qd`` is not given it is taken
from the not-a-knot cubic spline through ``q`` (so the plan is that spline). :meth:`MotionPlan.sample`,
:meth:`MotionPlan.check_limits` (vectorised numpy) and the simulation (Drake ``PiecewisePolynomial``)
use the same interpolation, so limit checks see what the robot is commanded.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from besdrake._io import write_text as _atomic_write_text
from besdrake.robot import JointLimits


#: Slower speeds (x the plan's) tried one after the other for a follow-through that breaks a joint limit
#: (:meth:`MotionPlan.with_follow_through_within`), and the time (s) over which the speed changes.
FOLLOW_THROUGH_FACTORS = (0.85, 0.7, 0.55, 0.4)
FOLLOW_THROUGH_WINDOW = 0.3
#: Share of each joint's acceleration limit that :meth:`MotionPlan.stopped_after` brakes a follow-through with.
BRAKE_SHARE = 0.9


def _speed_profile(at: float, factor: float, window: float):
    """Speed of :meth:`MotionPlan.slowed_after`'s warp against the plan's own time ``sigma``: 1 before ``at``, then a
    half cosine to ``factor`` over ``window``, ``factor`` after."""

    def rate(sigma: np.ndarray) -> np.ndarray:
        u = np.clip((np.asarray(sigma, dtype=float) - at) / window, 0.0, 1.0)
        return 1.0 + (factor - 1.0) * 0.5 * (1.0 - np.cos(np.pi * u))

    return rate


class PlanError(ValueError):
    """A motion plan is malformed (shape, NaN/inf, time) or violates the joint limits."""


class PlanLimitError(PlanError):
    """A motion plan commands joint positions beyond the robot's limits (velocity excess is flagged, not raised)."""


@dataclass
class LimitReport:
    """Largest violation per joint (0 where within the limit), in the limit's units.

    ``position`` in rad, ``velocity`` in rad/s, ``acceleration`` in rad/s^2; each has shape (n,) for the
    joints ``names``.
    """

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    names: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        """True when no joint exceeds any limit."""
        return not (np.any(self.position > 0) or np.any(self.velocity > 0) or np.any(self.acceleration > 0))

    def violations(self) -> list[str]:
        """Human-readable list of the violated limits, e.g. ``['joint2 position +0.120 rad']``."""
        out = []
        for kind, values, unit in (
            ("position", self.position, "rad"),
            ("velocity", self.velocity, "rad/s"),
            ("acceleration", self.acceleration, "rad/s^2"),
        ):
            names = self.names or tuple(f"joint{i + 1}" for i in range(len(values)))
            for name, v in zip(names, values):
                if v > 0:
                    out.append(f"{name} {kind} +{v:.3f} {unit}")
        return out

    def to_dict(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "position": self.position.tolist(),
            "velocity": self.velocity.tolist(),
            "acceleration": self.acceleration.tolist(),
        }


@dataclass
class MotionPlan:
    """A joint trajectory: ``t`` (N,) s from 0, ``q`` (N, n) rad, optional ``qd`` (N, n) rad/s; ``joint_names``
    (n) when known."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    joint_names: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float)
        self.q = np.asarray(self.q, dtype=float)
        if self.qd is not None:
            self.qd = np.asarray(self.qd, dtype=float)

    # ------------------------------------------------------------------ checks
    @property
    def duration(self) -> float:
        """Length of the plan in s (last time stamp)."""
        return float(self.t[-1]) if self.t.size else 0.0

    def validate(self) -> "MotionPlan":
        """Raise :class:`PlanError` naming the problem if the plan is malformed; return self."""
        if self.t.ndim != 1:
            raise PlanError(f"plan time must be a 1-D array, got shape {self.t.shape}")
        if self.t.size < 2:
            raise PlanError(f"plan needs at least 2 samples, got {self.t.size}")
        if self.q.ndim != 2 or self.q.shape[1] == 0:
            raise PlanError(f"plan q must be a 2-D array (samples x joints), got shape {self.q.shape}")
        if self.joint_names and len(set(self.joint_names)) != len(self.joint_names):
            raise PlanError(f"plan joint_names must be distinct, got {list(self.joint_names)}")
        n_joints = len(self.joint_names) if self.joint_names else self.q.shape[1]
        if self.q.shape != (self.t.size, n_joints):
            raise PlanError(f"plan q must have shape ({self.t.size}, {n_joints}), got {self.q.shape}")
        if self.qd is not None and self.qd.shape != self.q.shape:
            raise PlanError(f"plan qd must have the shape of q {self.q.shape}, got {self.qd.shape}")
        for name, arr in (("t", self.t), ("q", self.q), ("qd", self.qd)):
            if arr is not None and not np.all(np.isfinite(arr)):
                bad = np.argwhere(~np.isfinite(arr))[0]
                raise PlanError(f"plan {name} contains NaN or inf (first at index {tuple(int(i) for i in bad)})")
        if abs(self.t[0]) > 1e-9:
            raise PlanError(f"plan time must start at 0 s, starts at {self.t[0]:g} s")
        dt = np.diff(self.t)
        if np.any(dt <= 0):
            i = int(np.argmax(dt <= 0))
            raise PlanError(f"plan time must increase strictly; t[{i + 1}]={self.t[i + 1]:g} <= t[{i}]={self.t[i]:g}")
        return self

    def knot_velocities(self) -> np.ndarray:
        """Velocities (N, 6) at the samples: ``qd`` if given, else those of the not-a-knot spline through q."""
        if self.qd is not None:
            return self.qd
        from scipy.interpolate import CubicSpline

        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # absurd knots: inf/nan, flagged by _peaks
            try:
                return CubicSpline(self.t, self.q, axis=0, bc_type="not-a-knot")(self.t, 1)
            except ValueError as err:  # the slopes overflow
                raise PlanError(f"the plan's knots cannot be interpolated ({err})") from None

    def trajectory(self, time_shift: float = 0.0):
        """The plan as a Drake ``PiecewisePolynomial`` (cubic Hermite, 6 rows), optionally shifted by ``time_shift`` s."""
        from pydrake.trajectories import PiecewisePolynomial

        self.validate()
        return PiecewisePolynomial.CubicHermite(self.t + time_shift, self.q.T, self.knot_velocities().T)

    def _hermite(self, times: np.ndarray, qd: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions, velocities, accelerations (len(times), 6) of the Hermite interpolation (clamped at the ends).
        Absurd knots (fuzzed or corrupt files) give inf/nan here without a warning; :meth:`_peaks` flags them."""
        qd = self.knot_velocities() if qd is None else qd
        times = np.clip(np.asarray(times, dtype=float), 0.0, self.duration)
        i = np.clip(np.searchsorted(self.t, times, side="right") - 1, 0, self.t.size - 2)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            h = (self.t[i + 1] - self.t[i])[:, None]
            s = ((times - self.t[i])[:, None]) / h
            p0, p1, m0, m1 = self.q[i], self.q[i + 1], qd[i] * h, qd[i + 1] * h
            s2, s3 = s * s, s * s * s
            pos = (2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * m0 + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * m1
            vel = ((6 * s2 - 6 * s) * p0 + (3 * s2 - 4 * s + 1) * m0 + (-6 * s2 + 6 * s) * p1 + (3 * s2 - 2 * s) * m1) / h
            acc = ((12 * s - 6) * p0 + (6 * s - 4) * m0 + (-12 * s + 6) * p1 + (6 * s - 2) * m1) / (h * h)
        return pos, vel, acc

    def sample(self, times: np.ndarray, derivative: int = 0) -> np.ndarray:
        """Interpolated positions (derivative 0), velocities (1) or accelerations (2) at ``times``: (len(times), 6).
        Times outside [0, duration] are clamped (the plan holds its end points)."""
        self.validate()
        if derivative not in (0, 1, 2):
            raise ValueError(f"derivative must be 0, 1 or 2, got {derivative}")
        return self._hermite(np.atleast_1d(times))[derivative]

    def _sampled(self, resolution: float, until: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions, velocities and accelerations of the interpolated plan at the knots and at least every
        ``resolution`` s (up to ``until`` s where given); accelerations also just left of each knot (they jump there)."""
        n = max(2, int(np.ceil(self.duration / resolution)) + 1)
        ts = np.unique(np.concatenate([np.linspace(0.0, self.duration, n), self.t]))
        left = self.t[1:] - 1e-12
        if until is not None:
            ts, left = ts[ts <= until], left[left <= until]
        knot_qd = self.knot_velocities()  # one spline fit (when qd is not given) for both evaluations
        q, qd, qdd = self._hermite(ts, knot_qd)
        _, _, qdd_left = self._hermite(left, knot_qd)
        return q, qd, np.vstack([qdd, qdd_left])

    def slowed_after(self, at: float, factor: float, window: float = 0.3, knot_step: float | None = None) -> "MotionPlan":
        """The same path, played at ``factor`` x its speed from ``at`` s on (the speed changes smoothly, a half cosine
        over ``window`` s of the plan's own time; ``factor`` < 1 is slower): a time warp. Up to ``at`` the plan is this
        one, knot for knot; after it, knots every ``knot_step`` s (default: this plan's median step) hold the positions
        of the path and its velocities times the local factor, so the Hermite interpolation follows the warped path.
        What it is for: slowing a movement's follow-through, whose limits would otherwise cap how fast the part
        that matters may be played (:class:`besdrake.search.templates.MetaDMP`)."""
        self.validate()
        for name, v in (("at", at), ("factor", factor), ("window", window)):
            if not np.isfinite(v):
                raise PlanError(f"slowed_after: {name} must be finite, got {v!r}")
        if factor <= 0 or window <= 0 or not 0.0 <= at <= self.duration:
            raise PlanError(f"slowed_after: need factor > 0, window > 0 s and 0 <= at <= {self.duration:g} s, got {factor}, {window}, {at}")
        if at >= self.duration - 1e-9:  # nothing follows
            return MotionPlan(self.t.copy(), self.q.copy(), None if self.qd is None else self.qd.copy(), dict(self.meta), self.joint_names)
        rate = _speed_profile(at, float(factor), float(window))
        keep = self.t[self.t <= at]
        # the plan's own time from the last knot kept (the speed is 1 up to ``at``) and the warped time of each instant
        sigma = np.linspace(keep[-1], self.duration, max(2, int(np.ceil((self.duration - keep[-1]) / 5e-4)) + 1))
        inv = 1.0 / rate(sigma)
        t_new = keep[-1] + np.concatenate([[0.0], np.cumsum(0.5 * (inv[1:] + inv[:-1]) * np.diff(sigma))])
        step = float(np.median(np.diff(self.t))) if knot_step is None else float(knot_step)
        n = max(1, int(round((t_new[-1] - keep[-1]) / step)))
        later = np.linspace(keep[-1], t_new[-1], n + 1)[1:]
        s_later = np.interp(later, t_new, sigma)
        s_later[-1] = self.duration
        qd_keep = self.knot_velocities()[: keep.size]
        return MotionPlan(t=np.concatenate([keep, later]), q=np.vstack([self.q[: keep.size], self.sample(s_later)]),
                          qd=np.vstack([qd_keep, self.sample(s_later, 1) * rate(s_later)[:, None]]),
                          meta=dict(self.meta) | {"slowed_after_s": float(at), "slowed_factor": float(factor)},
                          joint_names=self.joint_names)

    def stopped_after(self, at: float, limits: JointLimits, share: float = BRAKE_SHARE) -> "MotionPlan":
        """This plan up to its first knot at or after ``at`` s, then every joint braked to rest at a constant
        deceleration (all joints stopping together, none beyond ``share`` of its acceleration limit): what is left of a
        follow-through when its path would leave the position limits. Knots keep this plan's median step."""
        self.validate()
        if not (np.isfinite(at) and np.isfinite(share) and 0.0 < share <= 1.0):
            raise PlanError(f"stopped_after: need a finite time and 0 < share <= 1, got {at!r}, {share!r}")
        k = int(np.searchsorted(self.t, at - 1e-12))
        if k >= self.t.size - 1:  # nothing follows
            return self
        qd_all = self.knot_velocities()
        q0, v0 = self.q[k], qd_all[k]
        acc = np.asarray(self._limits_for(limits).acceleration, dtype=float) * share
        stop = float(np.max(np.abs(v0) / acc))
        step = float(np.median(np.diff(self.t)))
        tau = np.linspace(0.0, stop, max(2, int(np.ceil(stop / step)) + 1))[1:] if stop > 0 else np.array([step])
        frac = np.minimum(tau / max(stop, 1e-12), 1.0)[:, None]  # 1 throughout where nothing moves (stop 0)
        q = q0 + v0 * tau[:, None] * (1.0 - 0.5 * frac)
        qd = v0 * (1.0 - frac)
        return MotionPlan(t=np.concatenate([self.t[: k + 1], self.t[k] + tau]), q=np.vstack([self.q[: k + 1], q]),
                          qd=np.vstack([qd_all[: k + 1], qd]),
                          meta=dict(self.meta) | {"stopped_after_s": float(self.t[k])}, joint_names=self.joint_names)

    def with_follow_through_within(self, limits: JointLimits, at: float, factors: tuple[float, ...] = FOLLOW_THROUGH_FACTORS,
                                   window: float = FOLLOW_THROUGH_WINDOW) -> "MotionPlan":
        """This plan where it keeps ``limits``, else the same path with everything after ``at`` s (a follow-through: the
        part that no longer changes the outcome) slowed by the first of ``factors`` that keeps them (:meth:`slowed_after`);
        this plan unchanged when none does (the limit check flags it)."""
        if self.check_limits(limits).ok or at >= self.duration - 1e-9:  # within the limits, or nothing follows
            return self
        for factor in factors:
            slowed = self.slowed_after(at, factor, window)
            if slowed.check_limits(limits).ok:
                return slowed
        return self

    def _limits_for(self, limits: JointLimits) -> JointLimits:
        if not isinstance(limits, JointLimits):
            raise TypeError(f"limits must be a robot's JointLimits, got {type(limits).__name__}")
        self.validate()
        if self.q.shape[1] != limits.n_joints:
            raise PlanError(f"plan has {self.q.shape[1]} joints, the robot {limits.n_joints} ({list(limits.names)})")
        if self.joint_names and tuple(self.joint_names) != tuple(limits.names):
            raise PlanError(f"plan joints {list(self.joint_names)} differ from the robot's {list(limits.names)}")
        return limits

    def _peaks(self, resolution: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per joint: lowest and highest position, largest |velocity| and |acceleration| of the interpolated plan,
        sampled as :meth:`_sampled` does. Kept on the plan (a few numbers per joint) for the next limit check of
        the same arrays: a candidate's plan is checked when it is retimed, simulated and rewarded."""
        key = (float(resolution),) + tuple(None if a is None else hash(a.tobytes()) for a in (self.t, self.q, self.qd))
        cached = self.__dict__.get("_peaks_cache")
        if cached is not None and cached[0] == key:
            return cached[1]
        q, qd, qdd = self._sampled(resolution)
        # A plan whose numbers overflow the interpolation (fuzzed or corrupt knots) must fail every limit, not pass
        # it through NaN comparisons: non-finite samples count as infinitely far out.
        bad = lambda a: ~np.isfinite(a).all(axis=0)  # noqa: E731
        peaks = (np.where(bad(q), -np.inf, np.min(q, axis=0)), np.where(bad(q), np.inf, np.max(q, axis=0)),
                 np.where(bad(qd), np.inf, np.max(np.abs(qd), axis=0)), np.where(bad(qdd), np.inf, np.max(np.abs(qdd), axis=0)))
        self.__dict__["_peaks_cache"] = (key, peaks)
        return peaks

    def check_limits(self, limits: JointLimits, resolution: float = 0.002) -> LimitReport:
        """Largest violation per joint of the interpolated plan against a robot's ``limits`` (sampled at the
        knots and at least every ``resolution`` s). Never raises for limit violations (it raises
        :class:`PlanError` for a malformed plan or one for other joints)."""
        limits = self._limits_for(limits)
        pos, vel, acc = limits.position, limits.velocity, limits.acceleration
        q_min, q_max, qd_peak, qdd_peak = self._peaks(resolution)
        # max_i(lo - q_i) == lo - min_i q_i exactly (rounding is monotonic), and so on: the per-sample form's figures
        p_viol = np.maximum(pos[:, 0] - q_min, q_max - pos[:, 1])
        v_viol = qd_peak - vel
        a_viol = qdd_peak - acc
        return LimitReport(
            position=np.maximum(p_viol, 0.0),
            velocity=np.maximum(v_viol, 0.0),
            acceleration=np.maximum(a_viol, 0.0),
            names=limits.names,
        )

    def peak_limit_ratios(self, limits: JointLimits, resolution: float = 0.002, until: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Peak |velocity| / velocity limit and peak |acceleration| / acceleration limit per joint (each (6,),
        dimensionless; > 1 where :meth:`check_limits` reports a violation), sampled as :meth:`check_limits` does
        (``until``: over the first ``until`` s only). Stretching a plan's time uniformly by ``k`` divides them by ``k``
        and ``k**2``."""
        limits = self._limits_for(limits)
        if until is None:
            _, _, qd_peak, qdd_peak = self._peaks(resolution)
        else:
            _, qd, qdd = self._sampled(resolution, until)
            qd_peak, qdd_peak = np.max(np.abs(qd), axis=0, initial=0.0), np.max(np.abs(qdd), axis=0, initial=0.0)
        return qd_peak / limits.velocity, qdd_peak / limits.acceleration

    # ------------------------------------------------------------------ I/O
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (units: s, rad, rad/s)."""
        d: dict[str, Any] = {"t": self.t.tolist(), "q": self.q.tolist()}
        if self.joint_names:
            d["joint_names"] = list(self.joint_names)
        if self.qd is not None:
            d["qd"] = self.qd.tolist()
        if self.meta:
            d["meta"] = self.meta
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "MotionPlan":
        """Inverse of :meth:`to_dict`; raises :class:`PlanError` for missing keys or a malformed plan."""
        if not isinstance(d, dict):
            raise PlanError(f"a motion plan must be a JSON object, got {type(d).__name__}")
        missing = [k for k in ("t", "q") if k not in d]
        if missing:
            raise PlanError(f"motion plan is missing key(s) {missing}")
        names = d.get("joint_names")
        if names is not None and (not isinstance(names, list) or not all(isinstance(n, str) for n in names)):
            raise PlanError(f"motion plan joint_names must be a list of names, got {names!r}")
        try:
            plan = cls(
                t=np.asarray(d["t"], dtype=float),
                q=np.asarray(d["q"], dtype=float),
                qd=None if d.get("qd") is None else np.asarray(d["qd"], dtype=float),
                meta=dict(d.get("meta") or {}),
                joint_names=tuple(names) if names else None,
            )
        except (TypeError, ValueError) as err:
            raise PlanError(f"motion plan arrays are not numeric or ragged: {err}") from err
        return plan.validate()

    def save(self, path: str | Path) -> Path:
        """Write the plan as JSON."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        _atomic_write_text(path, json.dumps(self.to_dict()))
        return path

    @classmethod
    def load(cls, path: str | Path) -> "MotionPlan":
        """Read a plan written by :meth:`save`; :class:`PlanError` for a missing or corrupt file."""
        path = Path(path)
        if not path.is_file():
            raise PlanError(f"motion plan file not found: {path}")
        try:
            d = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            raise PlanError(f"motion plan file {path} is not valid JSON: {err}") from err
        return cls.from_dict(d)
