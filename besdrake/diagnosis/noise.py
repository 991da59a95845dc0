"""Measurement noise per observable group, estimated from the log itself (never from the lab's config).

Preferred source: *pure error* from repeated plans (trials of the same plan, matched by content hash):
the pooled within-plan variance of every feature of a group. It contains everything that varies from
throw to throw (ball placement in the scoop, marker noise, encoder noise) and nothing systematic, so it is
the noise floor the simulation can at best reach. Without repeats the touchdown noise falls back to the
paper's figure (good throws repeat with 4.5-7 cm SD) and the other groups to what the signals themselves
show (marker noise from the ballistic-fit residuals, encoder noise from second differences); the result
says so (``source``).

The fit weighs every entry by its own SD (:meth:`NoiseModel.matrix`): a throw's features scatter by what its
ball placement does to that throw (``place_var``, predicted per throw and feature by simulating the plan at
several placements: a fast throw through the funnel's kink scatters by centimetres, a slow roll-out that lets
the ball settle first not at all) times a scale, plus a base SD; base and scale are fitted to the repeats'
within-plan variances per axis class (:data:`AXIS_CLASSES`: the horizontal and the vertical components of the
ball path apart). The per-group SDs (``sd``) stay the plain pooled figures the report prints.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize

from besdrake.diagnosis.observables import N_JOINT_TIMES, group_names, group_slices

#: Touchdown SD per axis (m) assumed when the log has no repeated plans (paper: 4.5-7 cm for good throws).
PRIOR_TOUCHDOWN_SD = 0.05
#: Smallest SD per group: what a simulation can be trusted to reproduce (2.5 ms step, linearisation; joint tracking
#: of a simulated servo is not accurate to better than ~1 mrad even when the encoders are finer).
FLOORS = {"touchdown": 0.003, "ball_pos": 0.002, "ball_vel": 0.01, "ball_acc": 0.05, "ball_rest": 0.001, "joints": 1e-3}
#: Typical noise of a group that the log does not contain (used only to judge what *would* separate causes).
TYPICAL = {"touchdown": 0.05, "ball_pos": 0.01, "ball_vel": 0.05, "ball_acc": 0.3, "ball_rest": 0.003, "joints": 1e-3}
#: Minimum degrees of freedom of the pure error before it is trusted.
MIN_DOF = 4
#: Largest factor on the simulated placement variance (the lab's scatter measured from repeats / the simulation's).
MAX_PLACEMENT_SCALE = 10.0
#: Feature indices within a group that share a base SD: horizontal (x, y) and vertical (z) parts of the ball path.
AXIS_CLASSES = {"touchdown": ((0, 1),), "ball_pos": ((0, 1), (2,)), "ball_vel": ((0, 1), (2,)), "ball_acc": ((0, 1), (2,)), "ball_rest": ((0, 1), (2,))}


@dataclass
class NoiseModel:
    """SD per group (in the group's unit), the degrees of freedom of each estimate (0: assumed/derived)
    and where it came from."""

    sd: dict[str, float]
    dof: dict[str, int]
    source: dict[str, str]
    n_repeat_groups: int = 0
    notes: list[str] = field(default_factory=list)
    #: Base SD per feature where the repeats measured it per axis class (NaN: use the group's ``sd``).
    feature_sd: np.ndarray | None = None
    #: Predicted placement variance per throw and feature (N, F), counted only where ``feature_sd`` is set.
    place_var: np.ndarray | None = None
    #: Factor on ``place_var`` per feature (the lab's placement scatter against the simulated one), from the repeats.
    place_scale: np.ndarray | None = None

    def vector(self) -> np.ndarray:
        """SD per feature (length of a feature vector): the group SDs."""
        sl = group_slices()
        out = np.empty(sl[group_names()[-1]].stop)
        for g, s in sl.items():
            out[s] = self.sd[g]
        return out

    def matrix(self, n: int) -> np.ndarray:
        """SD per throw and feature (n, F): sqrt(base^2 + scale * placement variance) where the repeats measured the
        base per axis class (the base alone when no placement variance is known for n throws), the group SD elsewhere."""
        v = self.vector()
        out = np.tile(v, (n, 1))
        if self.feature_sd is None:
            return out
        have = np.isfinite(self.feature_sd)
        ok = self.place_var is not None and len(self.place_var) == n
        pv = np.where(np.isfinite(self.place_var), self.place_var, 0.0) if ok else np.zeros_like(out)
        scale = np.ones_like(self.feature_sd) if self.place_scale is None else self.place_scale
        out[:, have] = np.sqrt(self.feature_sd[have] ** 2 + scale[have] * pv[:, have])
        return out

    def scale_group(self, g: str, factor: float) -> None:
        """Scale group ``g``'s SDs (group and per-feature) by ``factor``."""
        self.sd[g] *= factor
        if self.feature_sd is not None:
            self.feature_sd[group_slices()[g]] *= factor
        if self.place_scale is not None:
            self.place_scale[group_slices()[g]] *= factor**2

    def axis_sd(self) -> dict[str, dict[str, float]]:
        """The per-axis-class base SDs the fit weighs with and the factors on the simulated placement variance
        (``{group: {"horizontal": .., "horizontal_placement_scale": .., "vertical": .., ...}}``)."""
        if self.feature_sd is None:
            return {}
        sl, out = group_slices(), {}
        for g, classes in AXIS_CLASSES.items():
            for name, cls in zip(("horizontal", "vertical"), classes):
                j = sl[g].start + cls[0]
                if np.isfinite(self.feature_sd[j]):
                    out.setdefault(g, {})[name] = float(self.feature_sd[j])
                    if self.place_scale is not None:
                        out[g][name + "_placement_scale"] = float(self.place_scale[j])
        return out

    def to_dict(self) -> dict:
        return {"sd": dict(self.sd), "dof": dict(self.dof), "source": dict(self.source), "n_repeat_groups": self.n_repeat_groups, "notes": list(self.notes),
                "axis_sd_beyond_placement": self.axis_sd()}


def repeat_groups(keys: list[str]) -> list[list[int]]:
    """Row indices of the plans thrown more than once (rows sharing a key), in order of first appearance."""
    by_key: dict[str, list[int]] = {}
    for i, k in enumerate(keys):
        by_key.setdefault(k, []).append(i)
    return [idx for idx in by_key.values() if len(idx) > 1]


def pure_error(features: np.ndarray, keys: list[str]) -> dict[str, tuple[float, int]]:
    """Pooled within-plan SD and its dof per group, from rows of ``features`` sharing a key."""
    sl = group_slices()
    out: dict[str, tuple[float, int]] = {}
    groups = repeat_groups(keys)
    for g, s in sl.items():
        ss, dof, n_feat = 0.0, 0, s.stop - s.start
        for idx in groups:
            block = features[idx][:, s]
            rows = block[np.all(np.isfinite(block), axis=1)]
            if len(rows) < 2:
                continue
            ss += float(np.sum((rows - rows.mean(axis=0)) ** 2))
            dof += (len(rows) - 1) * n_feat
        if dof > 0:
            # The group's SD pools all its features (same unit, similar scale); dof counts every feature.
            out[g] = (float(np.sqrt(ss / dof)), dof)
    return out


def _class_fit(features: np.ndarray, keys: list[str], place_var: np.ndarray | None, cols: list[int]) -> tuple[float, float, int] | None:
    """Base SD and placement scale of the feature columns ``cols``: the repeats' within-plan variance of each plan and
    feature is modelled as ``base^2 + scale * place_var`` (the simulated placement scatter is only approximately
    the lab's), fitted by maximum likelihood (a within-plan variance with d dof is a scaled chi-square). A repeated
    probe, which the placement hardly moves, pins the base; the throws, the scale. Returns (base SD, scale, dof)
    or None without enough repeats."""
    v, pv, d = [], [], []
    for idx in repeat_groups(keys):
        block = features[idx][:, cols]
        ok = np.all(np.isfinite(block), axis=1)
        rows = block[ok]
        if len(rows) < 2:
            continue
        v += list(np.var(rows, axis=0, ddof=1))
        if place_var is not None:
            p = place_var[np.asarray(idx)[ok]][:, cols]
            pv += list(np.where(np.isfinite(p), p, 0.0).mean(axis=0))
        else:
            pv += [0.0] * len(cols)
        d += [len(rows) - 1] * len(cols)
    v, pv, d = np.array(v), np.array(pv), np.array(d, float)
    dof = int(d.sum())
    if dof < MIN_DOF:
        return None
    # d v / E ~ chi-square(d) with E = base^2 + scale * pv: minimise the negative log-likelihood over log base^2 and
    # log scale (from a few starts; without placement variance the scale is left at 0).
    tiny = 1e-14
    if not np.any(pv > 0):
        return float(np.sqrt(max(np.sum(d * v) / d.sum(), 0.0))), 0.0, dof

    def nll(x: np.ndarray) -> float:
        e = np.exp(x[0]) + np.exp(x[1]) * pv
        return float(np.sum(d * (np.log(e) + v / e)) / 2.0)

    lo, hi = np.log(tiny), np.log(max(float(v.max()), tiny) * 10.0)
    bounds = [(lo, hi), (np.log(1e-6), np.log(MAX_PLACEMENT_SCALE))]
    best = None
    for b0, c0 in ((float(np.median(v)), 1.0), (max(float(v.min()), tiny), 1.0), (max(float(v.min()), tiny), 3.0)):
        r = minimize(nll, np.clip([np.log(max(b0, tiny)), np.log(c0)], [b[0] for b in bounds], [b[1] for b in bounds]), method="L-BFGS-B", bounds=bounds)
        if best is None or r.fun < best.fun:
            best = r
    theta = np.exp(best.x)
    return float(np.sqrt(theta[0])), float(theta[1]), dof


def estimate_noise(features: np.ndarray, keys: list[str], mocap_sd: float | None, encoder_sd: float | None, ball_sd_from_fit: dict[str, float] | None = None,
                   place_var: np.ndarray | None = None) -> NoiseModel:
    """Noise per group from repeated plans where possible, else priors and signal-derived values; with repeats, also
    the per-axis-class base SDs beyond the predicted placement variance ``place_var`` (N, F) of each throw."""
    pe = pure_error(features, keys)
    n_rep = len(repeat_groups(keys))
    sd, dof, source, notes = {}, {}, {}, []
    for g in group_names():
        if g in pe and pe[g][1] >= MIN_DOF:
            sd[g], dof[g], source[g] = pe[g][0], pe[g][1], f"repeated plans ({pe[g][1]} dof)"
        elif g == "touchdown":
            sd[g], dof[g], source[g] = PRIOR_TOUCHDOWN_SD, 0, "assumed (paper: 4.5-7 cm SD; the log repeats no plan)"
            notes.append("no repeated plans: touchdown noise assumed 5 cm; repeat some plans to measure it")
        elif g == "joints" and encoder_sd is not None:
            sd[g], dof[g], source[g] = encoder_sd, 0, "encoder noise from second differences"
        elif g.startswith("ball") and ball_sd_from_fit and g in ball_sd_from_fit:
            sd[g], dof[g], source[g] = ball_sd_from_fit[g], 0, "marker noise propagated through the flight fit"
        else:
            sd[g], dof[g], source[g] = TYPICAL[g], 0, "typical value (not measured)"
        if sd[g] < FLOORS[g]:
            sd[g] = FLOORS[g]
            source[g] += f"; raised to the simulation floor {FLOORS[g]:g}"
    feature_sd = place_scale = None
    if n_rep:
        sl = group_slices()
        feature_sd = np.full(features.shape[1], np.nan)
        place_scale = np.zeros(features.shape[1])
        for g, classes in AXIS_CLASSES.items():
            if not str(source.get(g, "")).startswith("repeated plans"):
                continue
            for cls in classes:
                cols = [sl[g].start + j for j in cls]
                est = _class_fit(features, keys, place_var, cols)
                if est is None:
                    continue
                lo = max(FLOORS[g], (ball_sd_from_fit or {}).get(g, 0.0))
                feature_sd[cols] = max(est[0], lo)
                place_scale[cols] = est[1]
        if not np.isfinite(feature_sd).any():
            feature_sd = place_scale = None
    return NoiseModel(sd=sd, dof=dof, source=source, n_repeat_groups=n_rep, notes=notes, feature_sd=feature_sd, place_var=place_var, place_scale=place_scale)


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


__all__ = ["NoiseModel", "estimate_noise", "pure_error", "repeat_groups", "ball_fit_sd", "PRIOR_TOUCHDOWN_SD", "N_JOINT_TIMES"]
