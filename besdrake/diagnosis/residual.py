"""When nothing in the registry explains a log: where the residual lives, and a data-driven residual model.

The verdict stays "not explained". Beside it, :func:`residual_report` says

* **which observable** carries the residual (each measured group's share of the chi-square left by the chosen model),
* **which throws** (the largest standardised residuals, with their plans),
* **which plan features it follows**: Pearson correlation, over the throws, of each residual component of the
  touchdown with each behaviour feature (:func:`behaviour_features`: the nominal throw's landing, release velocity and
  height, and the plan's joint-1 sweep, joint-4 and joint-6 twists); those significant after Bonferroni,
* and a **data-driven residual model, labelled as such** (not a physical cause): ridge regression of the touchdown
  residual on the standardised behaviour features, with its own held-out gain (K-fold by plan: each throw predicted by
  a model fitted without its plan) against the model it corrects. A user sees what the residual follows (what to look
  for) and the model still gets better.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from besdrake.diagnosis import fitting
from besdrake.diagnosis.observables import group_slices

#: Ridge penalty on the standardised behaviour features (per throw, in units of the residual's variance).
RIDGE_ALPHA = 1.0
#: Correlations reported at this family-wise level (Bonferroni over features x touchdown axes).
FOLLOW_ALPHA = 0.01
LABEL = "data-driven residual model (ridge regression on behaviour features): not a physical cause"


@dataclass
class ResidualReport:
    """Where the residual of the chosen model lives, and the data-driven model of it (JSON via :meth:`to_dict`)."""

    group_share: dict[str, float]
    worst_throws: list[dict]
    follows: list[dict]
    model: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def describe(self) -> str:
        """One sentence for a verdict."""
        g = max(self.group_share, key=self.group_share.get) if self.group_share else "?"
        parts = [f"the residual lives mostly in {g} ({self.group_share.get(g, 0):.0%} of the chi-square)"]
        if self.follows:
            f = self.follows[0]
            parts.append(f"the touchdown {f['axis']} residual follows {f['feature']} (r = {f['r']:.2f})")
        if self.model.get("heldout_after_m") is not None:
            verb = "lowers" if self.model["better"] else "does not lower"
            parts.append(f"a {LABEL} {verb} the held-out touchdown disparity ({self.model['heldout_before_m'] * 100:.1f} -> "
                         f"{self.model['heldout_after_m'] * 100:.1f} cm, median)")
        return "; ".join(parts)


def behaviour_features(ev: Any) -> tuple[list[str], np.ndarray]:
    """Per used throw: the nominal landing (x, y), release velocity (the flight window's, 3) and height, and the plan's
    joint-1, joint-4 and joint-6 travel (last minus first sample, rad). NaN where the nominal flight is unknown."""
    sl = group_slices()
    full = ev.sim.full_cache.get(ev.sim.key({}))
    full = np.full_like(ev.y0, np.nan) if full is None else full
    names = ["touchdown_x", "touchdown_y", "vel_x", "vel_y", "vel_z", "height", "sweep_j1", "twist_j4", "twist_j6"]
    X = np.column_stack([full[:, sl["touchdown"]], full[:, sl["ball_vel"]], full[:, sl["ball_pos"]][:, 2],
                         np.array([p.q[-1, [0, 3, 5]] - p.q[0, [0, 3, 5]] for p in ev.plans])])
    return names, X


def _ridge(X: np.ndarray, Y: np.ndarray, alpha: float = RIDGE_ALPHA):
    """Ridge fit on standardised X (constant features dropped); returns a predict function."""
    mu, sd = X.mean(axis=0), X.std(axis=0)
    keep = sd > 1e-12
    Z = (X[:, keep] - mu[keep]) / sd[keep]
    y_mu = Y.mean(axis=0)
    W = np.linalg.solve(Z.T @ Z + alpha * len(Z) * np.eye(Z.shape[1]), Z.T @ (Y - y_mu))
    return lambda Xn: y_mu + ((Xn[:, keep] - mu[keep]) / sd[keep]) @ W


def residual_report(ev: Any, prob: fitting.Problem, y_model: np.ndarray, folds: int, rng: np.random.Generator) -> ResidualReport:
    """Where the residual of ``y_model`` (the chosen model's features, N x F) lives and the held-out gain of the
    data-driven residual model on the touchdowns (see the module docstring)."""
    sl = group_slices()
    c2 = fitting.chi2_by_group(prob, y_model, sl)
    total = sum(c2.get(g, 0.0) for g in ev.measured_groups) or 1.0
    share = {g: float(c2.get(g, 0.0) / total) for g in ev.measured_groups}
    r = prob.weighted(y_model)
    rows = np.nonzero(prob.mask)[0]
    per = np.bincount(rows, weights=r * r, minlength=len(ev.used))
    worst = [{"trial": ev.used[i].trial, "plan": ev.plans[i].meta.get("name") or ev.plans[i].meta.get("generator", ""), "chi2": float(per[i])}
             for i in np.argsort(-per)[:3]]
    names, X = behaviour_features(ev)
    td = sl["touchdown"]
    R = ev.y_meas[:, td] - y_model[:, td]
    ok = np.all(np.isfinite(X), axis=1) & np.all(np.isfinite(R), axis=1)
    return ResidualReport(share, worst, _follows(names, X[ok], R[ok]), _heldout(ev, names, X, R, ok, folds, rng))


def _follows(names: list[str], X: np.ndarray, R: np.ndarray) -> list[dict]:
    """Behaviour features the touchdown residual correlates with (Bonferroni over features x axes), strongest first."""
    out = []
    if len(X) < 5:
        return out
    m = X.shape[1] * R.shape[1]
    for j, name in enumerate(names):
        if np.std(X[:, j]) < 1e-12:
            continue
        for a, axis in enumerate(("x", "y")):
            rr, p = stats.pearsonr(X[:, j], R[:, a])
            if p * m < FOLLOW_ALPHA:
                out.append({"feature": name, "axis": axis, "r": float(rr), "p_bonferroni": float(min(1.0, p * m))})
    return sorted(out, key=lambda f: -abs(f["r"]))


def _heldout(ev: Any, names: list[str], X: np.ndarray, R: np.ndarray, ok: np.ndarray, folds: int, rng: np.random.Generator) -> dict[str, Any]:
    """K-fold (by plan) held-out touchdown disparity before/after adding the ridge-predicted residual."""
    idx = np.nonzero(ok)[0]
    uniq = sorted({ev.keys[i] for i in idx})
    if len(uniq) < max(folds, 4):
        return {"label": LABEL, "note": "too few distinct plans for a held-out gain"}
    order = rng.permutation(len(uniq))
    fold_of = {uniq[j]: k % folds for k, j in enumerate(order)}
    after = np.full(len(R), np.nan)
    for k in range(folds):
        test = [i for i in idx if fold_of[ev.keys[i]] == k]
        train = [i for i in idx if fold_of[ev.keys[i]] != k]
        if test and len(train) >= 4:
            pred = _ridge(X[train], R[train])(X[test])
            after[test] = np.linalg.norm(R[test] - pred, axis=1)
    before = np.linalg.norm(R, axis=1)
    done = np.isfinite(after)
    if not done.any():
        return {"label": LABEL, "note": "no fold could be fitted"}
    b, a = float(np.median(before[done])), float(np.median(after[done]))
    return {"label": LABEL, "features": names, "heldout_before_m": b, "heldout_after_m": a,
            "ratio_after_before": a / max(b, 1e-12), "n_heldout": int(done.sum()), "folds": folds, "better": a < b}
