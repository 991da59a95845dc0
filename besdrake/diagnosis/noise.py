"""The measurement noise a diagnosis compares against, estimated from the log itself (never from the lab's config).

Preferred source: *pure error* from repeated plans (trials of the same plan, matched by content hash): the pooled
within-plan variance of every feature of a group. It contains everything that varies from trial to trial (where an
object is placed, marker noise, encoder noise) and nothing systematic, so it is the noise floor the simulation can
at best reach. Without repeats the outcome noise falls back to the task's prior figure
(:attr:`~besdrake.diagnosis.trials.TrialModel.prior_outcome_sd`) and the other groups to what the signals themselves
show (:meth:`~besdrake.diagnosis.trials.TrialModel.signal_noise`, e.g. marker noise from path-fit residuals, encoder
noise from second differences) or their typical figure; the result says so (``source``).

The fit weighs every entry by its own SD (:meth:`NoiseModel.matrix`): a trial's features scatter by what the
placement scatter does to that trial (``place_var``, predicted per trial and feature by simulating the plan at
several placements: a fast motion through a kink of the placement scatters by centimetres, a slow one that lets the
object settle first not at all) times a scale, plus a base SD; base and scale are fitted to the repeats' within-plan
variances per axis class (:attr:`~besdrake.diagnosis.trials.Observable.axis_classes`, e.g. the horizontal and the
vertical components of a path apart). The per-group SDs (``sd``) stay the plain pooled figures the report prints.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize

from besdrake.diagnosis import settings
from besdrake.diagnosis.trials import SignalNoise, TrialModel, default_model

#: Minimum degrees of freedom of the pure error before it is trusted.
MIN_DOF = 4
#: Largest factor on the simulated placement variance (the lab's scatter measured from repeats / the simulation's).
MAX_PLACEMENT_SCALE = 10.0


@dataclass
class NoiseModel:
    """SD per group (in the group's unit), the degrees of freedom of each estimate (0: assumed/derived)
    and where it came from; ``model``: the task's trials (its groups; default: the default task's)."""

    sd: dict[str, float]
    dof: dict[str, int]
    source: dict[str, str]
    n_repeat_groups: int = 0
    notes: list[str] = field(default_factory=list)
    #: Base SD per feature where the repeats measured it per axis class (NaN: use the group's ``sd``).
    feature_sd: np.ndarray | None = None
    #: Predicted placement variance per trial and feature (N, F), counted only where ``feature_sd`` is set.
    place_var: np.ndarray | None = None
    #: Factor on ``place_var`` per feature (the lab's placement scatter against the simulated one), from the repeats.
    place_scale: np.ndarray | None = None
    model: TrialModel | None = field(default=None, repr=False, compare=False)
    #: Within-trial correlation of the features beyond the placement (F, F; :func:`base_correlation`), None: the features
    #: of a trial are taken as independent apart from the placement's part (or wholly, without ``place_cov``).
    base_corr: np.ndarray | None = None
    #: Covariance of a trial's features over the placement scatter (N, F, F; :attr:`_Sim.place_cov`).
    place_cov: np.ndarray | None = field(default=None, repr=False)
    #: Pure-error degrees of freedom of the repeats (one per extra trial of a repeated plan): how many independent
    #: looks at the noise along any one direction of a trial's features the log holds.
    repeat_dof: int = 0
    #: The log holds the outcome group alone (no other group measured in two trials or more).
    outcome_only: bool = False

    def __post_init__(self) -> None:
        if self.model is None:
            self.model = default_model()

    def vector(self) -> np.ndarray:
        """SD per feature (length of a feature vector): the group SDs."""
        sl = self.model.slices()
        out = np.empty(self.model.n_features)
        for g, s in sl.items():
            out[s] = self.sd[g]
        return out

    def matrix(self, n: int) -> np.ndarray:
        """SD per trial and feature (n, F): sqrt(base^2 + scale * placement variance) where the repeats measured the
        base per axis class (the base alone when no placement variance is known for n trials), the group SD elsewhere."""
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

    def floor_vector(self) -> np.ndarray:
        """The simulation floor per feature (:attr:`~besdrake.diagnosis.trials.Observable.floor`)."""
        out = np.empty(self.model.n_features)
        for o, s in zip(self.model.observables, self.model.slices().values()):
            out[s] = o.floor
        return out

    def covariances(self, n: int) -> np.ndarray | None:
        """Per trial the covariance of its features (n, F, F) with :meth:`matrix`'s SDs on the diagonal: the base part
        (base SDs, :attr:`base_corr`) plus the scaled placement covariance, its correlation applied to what lies above
        the simulation floor (the floor part of every feature stays independent, so that no combination of features is
        trusted beyond what the simulation reproduces). None when the diagonal model is asked for
        (``settings.WITHIN_TRIAL_COVARIANCE``, for a log of outcomes alone ``WITHIN_TRIAL_COVARIANCE_OUTCOME_ONLY``) or
        nothing correlates."""
        have_place = self.place_cov is not None and len(self.place_cov) == n and self.feature_sd is not None
        wanted = settings.WITHIN_TRIAL_COVARIANCE_OUTCOME_ONLY if self.outcome_only else settings.WITHIN_TRIAL_COVARIANCE
        if not wanted or (self.base_corr is None and not have_place):
            return None
        sd = self.matrix(n)
        base = self.vector()
        if self.feature_sd is not None:
            base = np.where(np.isfinite(self.feature_sd), self.feature_sd, base)
        R_b = np.eye(len(base)) if self.base_corr is None else self.base_corr
        cov = np.broadcast_to(R_b * np.outer(base, base), (n, len(base), len(base))).copy()
        if have_place:
            scale = np.where(np.isfinite(self.feature_sd), self.place_scale if self.place_scale is not None else 1.0, 0.0)
            cov += self.place_cov * np.sqrt(np.outer(scale, scale))[None]
        d = np.sqrt(np.clip(np.einsum("nii->ni", cov), 1e-300, None))
        R = cov / d[:, :, None] / d[:, None, :]
        phi = np.clip((self.floor_vector()[None, :] / sd) ** 2, 0.0, 1.0)
        q = np.sqrt(1.0 - phi)
        R = R * q[:, :, None] * q[:, None, :]
        idx = np.arange(R.shape[1])
        R[:, idx, idx] = 1.0
        return R * sd[:, :, None] * sd[:, None, :]

    def scale_group(self, g: str, factor: float) -> None:
        """Scale group ``g``'s SDs (group and per-feature) by ``factor``."""
        self.sd[g] *= factor
        if self.feature_sd is not None:
            self.feature_sd[self.model.slices()[g]] *= factor
        if self.place_scale is not None:
            self.place_scale[self.model.slices()[g]] *= factor**2

    def axis_sd(self) -> dict[str, dict[str, float]]:
        """The per-axis-class base SDs the fit weighs with and the factors on the simulated placement variance
        (``{group: {"horizontal": .., "horizontal_placement_scale": .., "vertical": .., ...}}``)."""
        if self.feature_sd is None:
            return {}
        sl, out = self.model.slices(), {}
        for g, classes in ((o.name, o.axis_classes) for o in self.model.observables if o.axis_classes):
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


def plan_rows(keys: list[str]) -> list[list[int]]:
    """The log's trials grouped by plan (rows sharing a key, the plan's content hash), in order of first appearance."""
    by_key: dict[str, list[int]] = {}
    for i, k in enumerate(keys):
        by_key.setdefault(k, []).append(i)
    return list(by_key.values())


def repeat_groups(keys: list[str]) -> list[list[int]]:
    """Row indices of the plans run more than once (rows sharing a key), in order of first appearance."""
    return [idx for idx in plan_rows(keys) if len(idx) > 1]


def pure_error(features: np.ndarray, keys: list[str], model: TrialModel | None = None) -> dict[str, tuple[float, int]]:
    """Pooled within-plan SD and its dof per group, from rows of ``features`` sharing a key."""
    sl = (model or default_model()).slices()
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
    the lab's), fitted by maximum likelihood (a within-plan variance with d dof is a scaled chi-square), with a
    log-normal prior around 1 on the scale where ``settings.PLACEMENT_SCALE_PRIOR_SD`` is set. A repeated plan the
    placement hardly moves pins the base; the others, the scale. Returns (base SD, scale, dof) or None without enough repeats."""
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
    # d v / E ~ chi-square(d) with E = base^2 + scale * pv: minimise the negative log-likelihood (plus the prior's term)
    # over log base^2 and log scale (from a few starts; without placement variance the scale is left at 0).
    tiny = 1e-14
    if not np.any(pv > 0):
        return float(np.sqrt(max(np.sum(d * v) / d.sum(), 0.0))), 0.0, dof

    prior_sd = settings.PLACEMENT_SCALE_PRIOR_SD

    def nll(x: np.ndarray) -> float:
        e = np.exp(x[0]) + np.exp(x[1]) * pv
        prior = 0.0 if prior_sd is None else 0.5 * (x[1] / prior_sd) ** 2
        return float(np.sum(d * (np.log(e) + v / e)) / 2.0) + prior

    lo, hi = np.log(tiny), np.log(max(float(v.max()), tiny) * 10.0)
    bounds = [(lo, hi), (np.log(1e-6), np.log(MAX_PLACEMENT_SCALE))]
    best = None
    for b0, c0 in ((float(np.median(v)), 1.0), (max(float(v.min()), tiny), 1.0), (max(float(v.min()), tiny), 3.0)):
        r = minimize(nll, np.clip([np.log(max(b0, tiny)), np.log(c0)], [b[0] for b in bounds], [b[1] for b in bounds]), method="L-BFGS-B", bounds=bounds)
        if best is None or r.fun < best.fun:
            best = r
    theta = np.exp(best.x)
    return float(np.sqrt(theta[0])), float(theta[1]), dof


def base_correlation(features: np.ndarray, keys: list[str], sd: np.ndarray, floor: np.ndarray, alpha: float) -> np.ndarray | None:
    """Within-trial correlation of the features from the repeats (F, F; None without two repeated plans).

    The within-plan deviations of every repeated plan, each feature in units of that trial's SD (``sd``, N x F), give
    a pooled sample correlation; with a handful of repeats most entries are noise (8 pairs: an SD of 0.35 about a
    true zero), and Ledoit-Wolf shrinkage, optimal over all entries at once, then shrinks the few strong ones too
    (benchmark log: intensity 0.88, a touchdown-path correlation of 1.00 kept as 0.12). So an entry is kept only
    where it is significant (t test of a correlation with the pure-error dof, at ``alpha`` Bonferroni over the pairs
    of features above the floor), else 0; features whose SD is the simulation floor (``floor``) stay independent.
    The result is made positive definite (eigenvalues at least ``settings.CORRELATION_EIGENVALUE_FLOOR``, unit diagonal)."""
    from scipy import stats as st

    dev = []
    for idx in repeat_groups(keys):
        block = features[idx]
        dev.append((block - block.mean(axis=0)) / sd[idx])
    if len(dev) < 2:
        return None
    Z = np.concatenate(dev)
    dof = sum(len(x) - 1 for x in dev)
    live = np.all(np.isfinite(Z), axis=0) & (np.nanmedian(sd, axis=0) > 1.05 * floor)
    F = features.shape[1]
    R = np.eye(F)
    m = int(live.sum())
    if m < 2 or dof < MIN_DOF:
        return None
    Zl = Z[:, live]
    C = Zl.T @ Zl / dof
    dd = np.sqrt(np.clip(np.diag(C), 1e-300, None))
    r = np.clip(C / np.outer(dd, dd), -1.0, 1.0)
    t = np.abs(r) * np.sqrt(max(dof - 2, 1)) / np.sqrt(np.clip(1.0 - r * r, 1e-12, None))
    p = 2.0 * st.t.sf(t, max(dof - 2, 1))
    keep = p < alpha / max(m * (m - 1) / 2, 1)
    r = np.where(keep, r, 0.0)
    np.fill_diagonal(r, 1.0)
    ev, V = np.linalg.eigh(r)
    r = (V * np.clip(ev, settings.CORRELATION_EIGENVALUE_FLOOR, None)) @ V.T
    d = np.sqrt(np.diag(r))
    R[np.ix_(live, live)] = r / np.outer(d, d)
    return R if np.any(keep & ~np.eye(m, dtype=bool)) else None


def estimate_noise(features: np.ndarray, keys: list[str], signal: SignalNoise | None = None, place_var: np.ndarray | None = None,
                   model: TrialModel | None = None, place_cov: np.ndarray | None = None) -> NoiseModel:
    """Noise per group from repeated plans where possible, else the outcome's prior, what the log's ``signal`` shows,
    or the group's typical figure; with repeats, also the per-axis-class base SDs beyond the predicted placement
    variance ``place_var`` (N, F) of each trial."""
    model = model or default_model()
    signal = signal or SignalNoise()
    pe = pure_error(features, keys, model)
    n_rep = len(repeat_groups(keys))
    sd, dof, source, notes = {}, {}, {}, []
    for o in model.observables:
        g = o.name
        if g in pe and pe[g][1] >= MIN_DOF:
            sd[g], dof[g], source[g] = pe[g][0], pe[g][1], f"repeated plans ({pe[g][1]} dof)"
        elif g == model.outcome:
            sd[g], dof[g], source[g] = model.prior_outcome_sd, 0, model.prior_outcome_source
            notes.append(model.prior_outcome_note)
        elif g in signal.sd:
            sd[g], dof[g], source[g] = signal.sd[g], 0, signal.source[g]
        else:
            sd[g], dof[g], source[g] = o.typical, 0, "typical value (not measured)"
        if sd[g] < o.floor:
            sd[g] = o.floor
            source[g] += f"; raised to the simulation floor {o.floor:g}"
    feature_sd = place_scale = None
    if n_rep:
        feature_sd, place_scale = _axis_fits(features, keys, place_var, model, source, signal)
    nm = NoiseModel(sd=sd, dof=dof, source=source, n_repeat_groups=n_rep, notes=notes, feature_sd=feature_sd, place_var=place_var,
                    place_scale=place_scale, model=model, place_cov=place_cov,
                    repeat_dof=sum(len(idx) - 1 for idx in repeat_groups(keys)), outcome_only=_outcome_only(features, model))
    if n_rep >= 2:
        nm.base_corr = base_correlation(features, keys, nm.matrix(len(features)), nm.floor_vector(), settings.ALPHA)
    return nm


def measured_groups(features: np.ndarray, model: TrialModel) -> list[str]:
    """The feature groups a log holds: those measured whole in two trials or more."""
    return [g for g, s in model.slices().items() if np.isfinite(features[:, s]).all(axis=1).sum() >= 2]


def _outcome_only(features: np.ndarray, model: TrialModel) -> bool:
    """Whether the log measured no group but the outcome (:func:`measured_groups`)."""
    return set(measured_groups(features, model)) <= {model.outcome}


def _axis_fits(features: np.ndarray, keys: list[str], place_var: np.ndarray | None, model: TrialModel, source: dict[str, str],
               signal: SignalNoise) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Base SD and placement scale per feature of the groups measured from repeats, per axis class (NaN / 0 elsewhere;
    None when no class could be fitted)."""
    sl = model.slices()
    feature_sd = np.full(features.shape[1], np.nan)
    place_scale = np.zeros(features.shape[1])
    for o in model.observables:
        if not o.axis_classes or not str(source.get(o.name, "")).startswith("repeated plans"):
            continue
        for cls in o.axis_classes:
            cols = [sl[o.name].start + j for j in cls]
            est = _class_fit(features, keys, place_var, cols)
            if est is None:
                continue
            lo = max(o.floor, signal.sd.get(o.name, 0.0) if o.name in signal.bounds else 0.0)
            feature_sd[cols] = max(est[0], lo)
            place_scale[cols] = est[1]
    if not np.isfinite(feature_sd).any():
        return None, None
    return feature_sd, place_scale


__all__ = ["NoiseModel", "estimate_noise", "plan_rows", "pure_error", "repeat_groups"]
