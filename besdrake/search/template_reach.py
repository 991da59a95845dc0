"""What a template's base can reach: a few simulated probes of the base over its execution time, the
meta-parameter box they imply, and the touchdown model they give the upper-level policy as prior knowledge.

With ``time_mode="scale"`` and ``joint1_mode="rotate"`` (:class:`~besdrake.search.templates.MetaDMP`) the
execution time plays the same path slower or faster, and the joint-1 goal rotates the whole movement about
the vertical axis of joint 1, which is the robot's base axis: the touchdown of ``(tau, goal1)`` is the touchdown
of ``(tau, base goal1)`` rotated by ``goal1 - base goal1`` about the origin. So probes along the execution time
alone (at the base's joint-1 goal) describe the whole meta-parameter box: a range ``r(tau)`` and a direction
``yaw(tau)`` per execution time, interpolated between the probes (:class:`ReachProbe`).

* :func:`probe_reach` simulates the probes (``n`` execution times, geometric grid).
* :func:`extend_probe` adds probes beyond the slowest one where that still lands beyond the nearest target.
* :func:`reach_meta_bounds` derives the box from them: execution times from the fastest within the joint limits
  down to the slowest that still reaches the context box's nearest target (the probes outside are cut), joint-1
  goals that turn the movement to every direction of the context box (within joint 1's limits).
* :class:`ReachPrior` is minus the squared distance between the modelled touchdown and the target: the prior
  mean of BO-CPS's reward model (:class:`PriorMeanGP`: the GP models what the probes did not capture) and,
  through :func:`prior_policy`, C-REPS's initial linear policy.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from besdrake.search.gp import GaussianProcess

#: Margin (m) beyond the context box's nearest radius that the slowest execution time must still reach.
RANGE_MARGIN = 0.05
#: Margin (rad) of the joint-1 goal range beyond the directions of the context box.
YAW_MARGIN = 0.1


@dataclass
class ReachProbe:
    """Touchdowns ``(n, 2)`` of the base at execution times ``taus`` (increasing; NaN rows: no touchdown) and
    its joint-1 goal ``goal1``; ``within_limits`` per probe."""

    taus: np.ndarray
    touchdowns: np.ndarray
    goal1: float
    within_limits: np.ndarray

    def __post_init__(self) -> None:
        self.taus = np.asarray(self.taus, dtype=float).ravel()
        self.touchdowns = np.asarray(self.touchdowns, dtype=float).reshape(-1, 2)
        self.within_limits = np.asarray(self.within_limits, dtype=bool).ravel()
        ok = np.isfinite(self.touchdowns).all(axis=1)
        if ok.sum() < 2:
            raise ValueError(f"a reach probe needs at least two probes with a touchdown, got {int(ok.sum())}")
        self._t = self.taus[ok]
        self._r = np.linalg.norm(self.touchdowns[ok], axis=1)
        self._yaw = np.unwrap(np.arctan2(self.touchdowns[ok, 1], self.touchdowns[ok, 0]))

    def range(self, tau: np.ndarray) -> np.ndarray:
        """Modelled touchdown distance from the robot (m) at execution time(s) ``tau`` (linear between probes)."""
        return np.interp(tau, self._t, self._r)

    def yaw(self, tau: np.ndarray) -> np.ndarray:
        """Modelled touchdown direction (rad, at the base's joint-1 goal) at execution time(s) ``tau``."""
        return np.interp(tau, self._t, self._yaw)

    def predict(self, theta: np.ndarray) -> np.ndarray:
        """Modelled touchdowns ``(n, 2)`` of meta-parameters ``theta`` ``(n, 2)`` = (execution time, joint-1 goal)."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        r, yaw = self.range(theta[:, 0]), self.yaw(theta[:, 0]) + theta[:, 1] - self.goal1
        return np.column_stack([r * np.cos(yaw), r * np.sin(yaw)])

    def to_dict(self) -> dict[str, Any]:
        return {"taus": self.taus.tolist(), "touchdowns": self.touchdowns.tolist(), "goal1": float(self.goal1),
                "within_limits": self.within_limits.tolist()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "ReachProbe":
        return cls(np.asarray(data["taus"], dtype=float), np.asarray(data["touchdowns"], dtype=float),
                   float(data["goal1"]), np.asarray(data["within_limits"], dtype=bool))

    def summary(self) -> dict[str, Any]:
        """Ranges and directions per probe (m, degrees)."""
        return {"taus_s": [round(float(t), 4) for t in self.taus],
                "range_m": [round(float(v), 4) for v in np.linalg.norm(self.touchdowns, axis=1)],
                "yaw_deg": [round(float(v), 2) for v in np.degrees(np.arctan2(self.touchdowns[:, 1], self.touchdowns[:, 0]))],
                "within_limits": self.within_limits.tolist()}


def probe_reach(meta, executor, tau_lo: float, tau_hi: float, n: int = 7) -> ReachProbe:
    """Simulate the base of ``meta`` (a :class:`~besdrake.search.templates.MetaDMP`) at ``n`` execution times
    from ``tau_lo`` to ``tau_hi`` (geometric grid) at its own joint-1 goal."""
    from besdrake.search.templates import touchdowns

    if not 0 < tau_lo < tau_hi or n < 2:
        raise ValueError(f"probe_reach needs 0 < tau_lo < tau_hi and n >= 2, got {tau_lo}, {tau_hi}, {n}")
    taus = np.geomspace(tau_lo, tau_hi, int(n))
    g1 = float(meta.base.goal[0])
    plans = [meta.plan(np.array([t, g1])) for t in taus]
    within = [bool(p.check_limits(meta.robot.limits).ok) for p in plans]
    return ReachProbe(taus, touchdowns(plans, executor), g1, np.array(within))


def extend_probe(probe: ReachProbe, meta, executor, context_bounds: np.ndarray, factor: float, n: int) -> ReachProbe:
    """``probe`` with ``n`` more probes beyond its slowest execution time, up to ``factor`` x it (geometric grid), where
    its slowest probe still lands beyond the context box's nearest target (less :data:`RANGE_MARGIN`): a movement that
    still lands far when played slower needs a slower end of the box for the near targets, while the probes within
    the first range keep their spacing (issue 27). Slower plays of a ``"scale"`` base stay within the joint limits."""
    from besdrake.search.templates import touchdowns

    r_near = context_polar_box(np.asarray(context_bounds, dtype=float))[0]
    slowest = float(probe.taus[-1])
    ranges = np.linalg.norm(probe.touchdowns, axis=1)
    if n < 1 or factor <= 1.0 or not np.isfinite(ranges[-1]) or ranges[-1] < r_near - RANGE_MARGIN:
        return probe
    taus = np.geomspace(slowest, factor * slowest, int(n) + 1)[1:]
    plans = [meta.plan(np.array([t, probe.goal1])) for t in taus]
    within = [bool(p.check_limits(meta.robot.limits).ok) for p in plans]
    return ReachProbe(np.concatenate([probe.taus, taus]), np.vstack([probe.touchdowns, touchdowns(plans, executor)]), probe.goal1,
                      np.concatenate([probe.within_limits, within]))


def context_polar_box(context_bounds: np.ndarray, n: int = 21) -> tuple[float, float, float, float]:
    """(nearest, farthest distance, smallest, largest direction) of the targets in a box of (x, y) contexts."""
    xs = np.linspace(context_bounds[0, 0], context_bounds[0, 1], n)
    ys = np.linspace(context_bounds[1, 0], context_bounds[1, 1], n)
    X, Y = np.meshgrid(xs, ys)
    r, yaw = np.hypot(X, Y), np.arctan2(Y, X)
    return float(r.min()), float(r.max()), float(yaw.min()), float(yaw.max())


def reach_meta_bounds(probe: ReachProbe, safe_bounds: np.ndarray, context_bounds: np.ndarray) -> np.ndarray:
    """The meta-parameter box the probes call for, inside ``safe_bounds`` (within the joint limits).

    Execution time: from the fastest safe one to the first probe that lands nearer than the context box's nearest
    target (less :data:`RANGE_MARGIN`), or the slowest safe one; where even the fastest lands short (a base that
    cannot reach the box: the template then misses by range, and says so in its distances) the safe range stays
    whole. Joint-1 goal: the goals that turn every probe within those times to every direction of the context box
    (plus :data:`YAW_MARGIN`), clipped to the safe range.
    """
    safe_bounds = np.asarray(safe_bounds, dtype=float)
    r_near, _, yaw_lo, yaw_hi = context_polar_box(np.asarray(context_bounds, dtype=float))
    lo, hi = safe_bounds[0]
    inside = (probe.taus >= lo - 1e-9) & (probe.taus <= hi + 1e-9)
    short = inside & (np.linalg.norm(probe.touchdowns, axis=1) < r_near - RANGE_MARGIN)
    first_short = float(probe.taus[np.flatnonzero(short)[0]]) if short.any() else np.inf
    if first_short > lo:
        hi = min(hi, first_short)
    taus = np.linspace(lo, hi, 25)
    yaws = probe.yaw(taus)
    g_lo = probe.goal1 + yaw_lo - YAW_MARGIN - float(yaws.max())
    g_hi = probe.goal1 + yaw_hi + YAW_MARGIN - float(yaws.min())
    box = np.array([[lo, hi], [max(g_lo, safe_bounds[1, 0]), min(g_hi, safe_bounds[1, 1])]])
    if box[1, 0] >= box[1, 1]:
        box[1] = safe_bounds[1]
    return box


def model_floor(probe: ReachProbe, bounds: np.ndarray, contexts: np.ndarray, n: int = 80) -> np.ndarray:
    """Per context (m): the distance to the nearest modelled touchdown over the box ``bounds`` (``n`` x ``n`` grid):
    what no choice of the two meta-parameters avoids, by range or by direction (up to the model's error)."""
    grid = np.array([[t, g] for t in np.linspace(*bounds[0], n) for g in np.linspace(*bounds[1], n)])
    td = probe.predict(grid)
    contexts = np.atleast_2d(np.asarray(contexts, dtype=float))
    return np.min(np.linalg.norm(td[None, :, :] - contexts[:, None, :], axis=2), axis=1)


def saturate(reward: np.ndarray, scale: float | None) -> np.ndarray:
    """``-scale * log(1 + d^2 / scale)`` of a reward ``-d^2`` (m^2): the reward itself for ``d^2`` well below ``scale``,
    growing only logarithmically beyond; ``scale`` None: the reward unchanged."""
    reward = np.asarray(reward, dtype=float)
    if scale is None:
        return reward
    return -scale * np.log1p(-np.minimum(reward, 0.0) / scale)


class ReachPrior:
    """Prior of BO-CPS inputs ``(context, theta)``: minus the squared distance (m^2) from the probes' modelled
    touchdown of ``theta`` to the target ``context``, saturated (:func:`saturate`) where ``saturation`` (m^2) is given.

    The GP then models the observed reward, saturated alike (:meth:`transform`), minus this prior. The probes' model
    misses a touchdown by a few centimetres anywhere, and a reward ``-d^2`` turns that into a residual of about
    ``2 d`` times the model's error: tens of times larger at a 2 m miss than near a target, which the GP's one
    noise level and amplitude cannot describe. Saturated, the residual stays within ``sqrt(saturation)`` times the
    model's error everywhere and is still the reward's own near the targets, where the policy is decided."""

    def __init__(self, probe: ReachProbe, n_context: int = 2, saturation: float | None = None) -> None:
        self.probe = probe
        self.n_context = int(n_context)
        if saturation is not None and not (np.isfinite(saturation) and saturation > 0):
            raise ValueError(f"saturation must be a positive number of m^2 or None, got {saturation!r}")
        self.saturation = None if saturation is None else float(saturation)

    def __call__(self, X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, dtype=float))
        td = self.probe.predict(X[:, self.n_context:])
        return saturate(-np.sum((td - X[:, : self.n_context]) ** 2, axis=1), self.saturation)

    def transform(self, reward: np.ndarray) -> np.ndarray:
        """Observed rewards (m^2) on the scale this prior and the GP model."""
        return saturate(reward, self.saturation)


def prior_policy(probe: ReachProbe, bounds: np.ndarray, contexts: np.ndarray) -> np.ndarray:
    """Meta-parameters ``(n, 2)`` whose modelled touchdowns come nearest to ``contexts`` ``(n, 2)`` within ``bounds``:
    the execution time whose range is nearest the target's distance (grid of 200), the joint-1 goal that turns
    its direction onto the target's."""
    contexts = np.atleast_2d(np.asarray(contexts, dtype=float))
    taus = np.linspace(bounds[0, 0], bounds[0, 1], 200)
    ranges = probe.range(taus)
    out = np.empty((len(contexts), 2))
    for i, s in enumerate(contexts):
        tau = taus[int(np.argmin(np.abs(ranges - np.hypot(*s))))]
        goal = probe.goal1 + np.arctan2(s[1], s[0]) - float(probe.yaw(tau))
        out[i] = [tau, np.clip(goal, bounds[1, 0], bounds[1, 1])]
    return out


def prior_from_dict(data: dict[str, Any], n_context: int) -> ReachPrior:
    """The prior a BO-CPS state names (``{"type": "reach", "probe": ReachProbe.to_dict(), "saturation": m^2}``; a state
    without ``saturation``, written before it existed, models the reward unsaturated)."""
    if not isinstance(data, dict) or data.get("type") != "reach" or "probe" not in data:
        raise ValueError(f"unknown prior mean {data!r}: expected {{'type': 'reach', 'probe': ...}}")
    return ReachPrior(ReachProbe.from_dict(data["probe"]), n_context, data.get("saturation"))


class PriorMeanGP(GaussianProcess):
    """A :class:`GaussianProcess` of the residual ``prior.transform(y) - prior(X)``: it predicts ``prior(X) +`` the
    residual's posterior (the reward itself, or saturated where the prior saturates it: the same maximisers).

    Built from a (fitted or empty) GP by :meth:`wrap`; its state is the residual GP's (the prior is kept by whoever
    owns it, e.g. the template record, and wrapped again on load)."""

    prior: ReachPrior

    @classmethod
    def wrap(cls, gp: GaussianProcess, prior: ReachPrior) -> "PriorMeanGP":
        new = cls.__new__(cls)
        new.__dict__.update(gp.__dict__)
        new.prior = prior
        return new

    def fit(self, X: np.ndarray, y: np.ndarray, optimize: bool = True) -> "PriorMeanGP":
        X = np.atleast_2d(np.asarray(X, dtype=float))
        return super().fit(X, self.prior.transform(np.asarray(y, dtype=float).ravel()) - self.prior(X), optimize)

    def predict(self, X: np.ndarray, return_std: bool = False):
        out = super().predict(X, return_std)
        m = self.prior(X)
        return (out[0] + m, out[1]) if return_std else out + m

    def posterior(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        mean, cov = super().posterior(X)
        return mean + self.prior(X), cov


__all__ = ["ReachProbe", "extend_probe", "ReachPrior", "saturate", "PriorMeanGP", "prior_from_dict", "model_floor", "probe_reach",
           "reach_meta_bounds", "prior_policy",
           "context_polar_box", "RANGE_MARGIN", "YAW_MARGIN"]
