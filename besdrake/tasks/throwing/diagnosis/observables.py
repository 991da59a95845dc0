"""Per-throw observables compared between the lab and the simulation (the throwing task's diagnosis features).

The same feature extraction is applied to a measured trial and to a simulated :class:`~besdrake.sim.Outcome`
of the same plan, so that sim and lab are compared like for like:

* ``touchdown`` (2): (x, y) on the floor, m.
* ``ball_pos`` / ``ball_vel`` / ``ball_acc`` (3 each): a quadratic fit per axis of the ball's path in a
  fixed flight window (from the nominal simulation: 0.08 s after its release to 0.05 s before its touchdown)
  at the measured sample times: position (m) and velocity (m/s) at the window's centre time and the
  acceleration (m/s^2). They carry the release state (position, speed, direction, timing) and the in-flight
  forces (drag shows as a horizontal deceleration).
* ``ball_rest`` (3): the ball's marker in the scoop before the throw, m (mean of the samples in the first
  :data:`REST_TIME` s). Where the ball sits shows the arm's base and posture (base and joint offsets, servo sag),
  the ball's size and how it is put into the scoop (the funnel lifts an off-centre ball), independently of the
  flight.
* ``joints`` (6 x :data:`N_JOINT_TIMES`): tracking error, measured minus commanded joint angle (rad), at
  fixed times spread over the nominal swing up to the nominal release. Lag, delay and servo gains show here.

A :class:`ThrowLayout` (windows and times per throw) is built once from the nominal simulation and reused for
every simulated variant, so the features are smooth functions of the effect parameters. The diagnosis engine
(:mod:`besdrake.diagnosis`) reads them through :class:`besdrake.tasks.throwing.diagnosis.model.ThrowDiagnosis`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Feature groups in the order they appear in a feature vector, with their sizes and units.
GROUPS: dict[str, tuple[int, str]] = {
    "touchdown": (2, "m"),
    "ball_pos": (3, "m"),
    "ball_vel": (3, "m/s"),
    "ball_acc": (3, "m/s^2"),
    "ball_rest": (3, "m"),
}
#: Number of sample times of the joint tracking error per joint.
N_JOINT_TIMES = 8
JOINT_GROUP = ("joints", 6 * N_JOINT_TIMES, "rad")
#: Flight window relative to the nominal release and touchdown (s).
WINDOW_AFTER_RELEASE = 0.08
WINDOW_BEFORE_TOUCHDOWN = 0.05
#: Minimum number of measured ball samples in the window for the path features.
MIN_BALL_SAMPLES = 8
#: The ball at rest: marker samples from the start of the trial up to this time (s); at least MIN_REST_SAMPLES.
#: A plan may start moving at once, but 30 ms into a smooth start the scoop has hardly moved, and the simulation is
#: read at the same sample times.
REST_TIME = 0.03
MIN_REST_SAMPLES = 2
#: Measurement flags that make a trial unusable for the comparison.
UNUSABLE_FLAGS = ("refused_by_safety_gate", "never_released", "dropped_early", "aborted")


def group_names() -> list[str]:
    return [*GROUPS, JOINT_GROUP[0]]


def group_slices() -> dict[str, slice]:
    out, i = {}, 0
    for name, (n, _unit) in [*GROUPS.items(), (JOINT_GROUP[0], JOINT_GROUP[1:])]:
        out[name] = slice(i, i + n)
        i += n
    return out


N_FEATURES = sum(n for n, _ in GROUPS.values()) + JOINT_GROUP[1]
GROUP_UNITS = {**{k: u for k, (_, u) in GROUPS.items()}, JOINT_GROUP[0]: JOINT_GROUP[2]}


@dataclass
class ThrowLayout:
    """Where to read the features of one throw (derived from the measured trial and the nominal rollout)."""

    ball_times: np.ndarray | None = None  # measured sample times inside the flight window
    ball_center: float = 0.0  # centre time of the quadratic fit (s)
    rest_times: np.ndarray | None = None  # measured sample times of the ball at rest in the scoop
    joint_times: np.ndarray | None = None  # times of the tracking-error samples (s)
    release_time_nominal: float | None = None
    touchdown_time_nominal: float | None = None
    notes: list[str] = field(default_factory=list)


def _quadratic_fit(t: np.ndarray, p: np.ndarray, tc: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares ``p(t) = p0 + v (t - tc) + a/2 (t - tc)^2`` per axis; returns p0, v, a and residuals."""
    s = t - tc
    A = np.column_stack([np.ones_like(s), s, 0.5 * s * s])
    coef, *_ = np.linalg.lstsq(A, p, rcond=None)
    res = p - A @ coef
    return coef[0], coef[1], coef[2], res


def make_layout(measurement, nominal) -> ThrowLayout:
    """Layout of one throw from its measurement and the nominal :class:`Outcome` of its plan."""
    lay = ThrowLayout()
    if nominal.release_time is None or nominal.touchdown_time is None:
        lay.notes.append("nominal simulation did not release the ball")
        return lay
    lay.release_time_nominal = float(nominal.release_time)
    lay.touchdown_time_nominal = float(nominal.touchdown_time)
    if measurement.ball_path is not None and len(measurement.ball_t):
        t = np.asarray(measurement.ball_t, float)
        p = np.asarray(measurement.ball_path, float)
        lo = nominal.release_time + WINDOW_AFTER_RELEASE
        hi = nominal.touchdown_time - WINDOW_BEFORE_TOUCHDOWN
        ok = (t >= lo) & (t <= hi) & np.all(np.isfinite(p), axis=1)
        if ok.sum() >= MIN_BALL_SAMPLES:
            lay.ball_times = t[ok]
            lay.ball_center = float(np.mean(t[ok]))
        else:
            lay.notes.append(f"only {int(ok.sum())} ball samples in the flight window")
        rest = (t >= 0.0) & (t <= REST_TIME + 1e-9) & np.all(np.isfinite(p), axis=1)
        if rest.sum() >= MIN_REST_SAMPLES:
            lay.rest_times = t[rest]
    if measurement.joint_t is not None and len(measurement.joint_t) > 2:
        jt = np.asarray(measurement.joint_t, float)
        t_end = min(nominal.release_time, jt[-1])
        t0 = max(jt[0], 0.0)
        if t_end > t0:
            lay.joint_times = np.linspace(t0 + (t_end - t0) / N_JOINT_TIMES, t_end, N_JOINT_TIMES)
    return lay


def full_layout(layout: ThrowLayout) -> ThrowLayout:
    """A layout with every group (100 Hz flight window, joint grid) for predictions of unmeasured signals."""
    full = ThrowLayout(ball_times=layout.ball_times, ball_center=layout.ball_center, rest_times=layout.rest_times, joint_times=layout.joint_times,
                       release_time_nominal=layout.release_time_nominal, touchdown_time_nominal=layout.touchdown_time_nominal)
    if layout.release_time_nominal is None:
        return full
    if full.ball_times is None:
        t = np.arange(layout.release_time_nominal + WINDOW_AFTER_RELEASE, layout.touchdown_time_nominal - WINDOW_BEFORE_TOUCHDOWN, 0.01)
        if len(t) >= MIN_BALL_SAMPLES:
            full.ball_times, full.ball_center = t, float(t.mean())
    if full.rest_times is None:
        full.rest_times = np.arange(0.0, REST_TIME + 1e-9, 0.005)
    if full.joint_times is None:
        t_end = layout.release_time_nominal
        full.joint_times = np.linspace(t_end / N_JOINT_TIMES, t_end, N_JOINT_TIMES)
    return full


def _interp_rows(tq: np.ndarray, t: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(tq, t, y[:, j]) for j in range(y.shape[1])])


def measured_features(measurement, layout: ThrowLayout) -> tuple[np.ndarray, float | None]:
    """Feature vector (NaN where not measured) of a measured trial, and the RMS of its ball-path fit residual."""
    f = np.full(N_FEATURES, np.nan)
    sl = group_slices()
    if measurement.touchdown is not None and not measurement.flags.get("ball_not_seen", False):
        f[sl["touchdown"]] = measurement.touchdown
    rms = None
    if layout.ball_times is not None or layout.rest_times is not None:
        t = np.asarray(measurement.ball_t, float)
        p = np.asarray(measurement.ball_path, float)
        seen = np.all(np.isfinite(p), axis=1)
    if layout.ball_times is not None:
        sel = np.isin(t, layout.ball_times) & seen
        p0, v, a, res = _quadratic_fit(t[sel], p[sel], layout.ball_center)
        f[sl["ball_pos"]], f[sl["ball_vel"]], f[sl["ball_acc"]] = p0, v, a
        rms = float(np.sqrt(np.mean(res**2)))
    if layout.rest_times is not None:
        sel = np.isin(t, layout.rest_times) & seen
        if sel.sum() >= MIN_REST_SAMPLES:
            f[sl["ball_rest"]] = p[sel].mean(axis=0)
    if layout.joint_times is not None:
        jt = np.asarray(measurement.joint_t, float)
        err = np.asarray(measurement.q_measured, float) - np.asarray(measurement.q_commanded, float)
        f[sl["joints"]] = _interp_rows(layout.joint_times, jt, err).T.ravel()
    return f, rms


def simulated_features(outcome, layout: ThrowLayout) -> np.ndarray:
    """Feature vector of a simulated :class:`Outcome` read at the layout's windows (NaN if the sim failed)."""
    f = np.full(N_FEATURES, np.nan)
    sl = group_slices()
    if outcome.touchdown is None or outcome.flags.get("sim_failed") or outcome.flags.get("never_released"):
        return f
    f[sl["touchdown"]] = outcome.touchdown
    if layout.ball_times is not None and len(outcome.ball_t) > 1:
        path = _interp_rows(layout.ball_times, outcome.ball_t, outcome.ball_path)
        p0, v, a, _ = _quadratic_fit(layout.ball_times, path, layout.ball_center)
        f[sl["ball_pos"]], f[sl["ball_vel"]], f[sl["ball_acc"]] = p0, v, a
    if layout.rest_times is not None and len(outcome.ball_t) > 1:
        f[sl["ball_rest"]] = _interp_rows(layout.rest_times, outcome.ball_t, outcome.ball_path).mean(axis=0)
    if layout.joint_times is not None and len(outcome.joint_t) > 1:
        err = outcome.q_measured - outcome.q_commanded
        f[sl["joints"]] = _interp_rows(layout.joint_times, outcome.joint_t, err).T.ravel()
    return f


def release_state(features: np.ndarray, layout: ThrowLayout) -> tuple[np.ndarray, np.ndarray] | None:
    """Ball position and velocity extrapolated from the flight fit back to the nominal release time."""
    sl = group_slices()
    if layout.release_time_nominal is None or not np.isfinite(features[sl["ball_acc"]]).all():
        return None
    dt = layout.release_time_nominal - layout.ball_center
    p0, v, a = features[sl["ball_pos"]], features[sl["ball_vel"]], features[sl["ball_acc"]]
    return p0 + v * dt + 0.5 * a * dt * dt, v + a * dt


def tracking_lag(features: np.ndarray, layout: ThrowLayout, plan) -> float | None:
    """Time (s) by which the joints lag the command: least squares of error = -lag * commanded velocity."""
    sl = group_slices()
    if layout.joint_times is None or not np.isfinite(features[sl["joints"]]).all():
        return None
    err = features[sl["joints"]].reshape(6, N_JOINT_TIMES).T
    qd = plan.sample(layout.joint_times, 1)
    den = float(np.sum(qd * qd))
    return None if den < 1e-9 else float(-np.sum(err * qd) / den)


def usable(measurement) -> tuple[bool, str]:
    """Whether a trial can be compared with the simulation, and why not."""
    raised = [k for k in UNUSABLE_FLAGS if measurement.flags.get(k, False)]
    if raised:
        return False, "flags: " + ", ".join(raised)
    if measurement.touchdown is None and measurement.ball_path is None and measurement.joint_t is None:
        return False, "nothing measured"
    return True, ""


def mocap_noise_from_residuals(rms_values: list[float]) -> float | None:
    """Marker noise SD (m) from the RMS residuals of the per-throw quadratic fits (median, robust)."""
    vals = [r for r in rms_values if r is not None and np.isfinite(r)]
    return float(np.median(vals)) if vals else None


def encoder_noise(measurements) -> float | None:
    """Encoder noise SD (rad) from the second differences of the tracking error (robust MAD / sqrt(6))."""
    vals = []
    for m in measurements:
        if m.q_measured is None or len(m.q_measured) < 5:
            continue
        err = np.asarray(m.q_measured, float) - np.asarray(m.q_commanded, float)
        d2 = np.diff(err, 2, axis=0).ravel()
        d2 = d2[np.isfinite(d2)]
        if d2.size:
            vals.append(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))
    return float(np.median(vals)) if vals else None


def ball_fit_sd(layout_times: list[np.ndarray], centers: list[float], mocap_sd: float | None,
                rest_times: list[np.ndarray | None] | None = None) -> dict[str, float]:
    """SD of the flight-fit coefficients (position, velocity, acceleration) for marker noise ``mocap_sd``, and of the
    mean ball position at rest (``ball_rest``, from the rest samples per throw)."""
    if mocap_sd is None:
        return {}
    rest = [len(t) for t in (rest_times or []) if t is not None and len(t)]
    out_rest = {"ball_rest": float(mocap_sd / np.sqrt(np.median(rest)))} if rest else {}
    vals = []
    for t, tc in zip(layout_times, centers):
        if t is None:
            continue
        s = t - tc
        A = np.column_stack([np.ones_like(s), s, 0.5 * s * s])
        vals.append(np.sqrt(np.diag(np.linalg.inv(A.T @ A))) * mocap_sd)
    if not vals:
        return out_rest
    v = np.median(np.array(vals), axis=0)
    return {"ball_pos": float(v[0]), "ball_vel": float(v[1]), "ball_acc": float(v[2]), **out_rest}
