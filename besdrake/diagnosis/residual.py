"""When nothing in the registry explains a log: where the residual lives, and a data-driven residual model.

The verdict stays "not explained". Beside it, :func:`residual_report` says

* **which observable** carries the residual (each measured group's share of the chi-square left by the chosen model),
* **which trials** (the largest standardised residuals, with their plans),
* **which plan features it follows**: Pearson correlation, over the trials, of each residual component of the
  outcome with each behaviour feature (:func:`behaviour_features`, the task's
  :meth:`~besdrake.diagnosis.trials.TrialModel.behaviour_features`, e.g. where the nominal trial ends and how the plan
  moves); those significant after Bonferroni,
* and a **data-driven residual model, labelled as such** (not a physical cause): a ridge regression of the outcome
  residual on the behaviour features whose features and penalty are chosen by leave-one-plan-out cross-validation
  (:class:`~besdrake.diagnosis.residual_model.ResidualModel`), with its own held-out gain against the model it
  corrects: nested K-fold by plan (:data:`HELDOUT_FOLDS`, :data:`HELDOUT_REPEATS` random splits), the whole choice
  refitted without the held-out plans. It is **offered only when that held-out gain is positive** (median and RMS); otherwise the report says so ("no gain") and offers none. A
  user sees what the residual follows (what to look for) and, where the data allow, the model still gets better.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from besdrake.diagnosis import fitting
from besdrake.diagnosis.residual_model import ResidualModel, nested_heldout

#: Outer folds (by plan) of the residual model's held-out gain (at least the diagnosis' own K).
HELDOUT_FOLDS = 5
#: ... repeated with this many random splits (the gain of one split of about 17 plans is itself noisy).
HELDOUT_REPEATS = 3
#: Correlations reported at this family-wise level (Bonferroni over features x outcome axes).
FOLLOW_ALPHA = 0.01
LABEL = "data-driven residual model (ridge regression on cross-validated behaviour features): not a physical cause"


@dataclass
class ResidualReport:
    """Where the residual of the chosen model lives, and the data-driven model of it (JSON via :meth:`to_dict`)."""

    group_share: dict[str, float]
    worst_trials: list[dict]
    follows: list[dict]
    model: dict[str, Any] = field(default_factory=dict)
    outcome: str = "outcome"

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        del d["outcome"]
        return d

    def describe(self) -> str:
        """One sentence for a verdict."""
        g = max(self.group_share, key=self.group_share.get) if self.group_share else "?"
        parts = [f"the residual lives mostly in {g} ({self.group_share.get(g, 0):.0%} of the chi-square)"]
        if self.follows:
            f = self.follows[0]
            parts.append(f"the {self.outcome} {f['axis']} residual follows {f['feature']} (r = {f['r']:.2f})")
        m = self.model
        if m.get("heldout_after_m") is not None:
            figs = f"{m['heldout_before_m'] * 100:.1f} -> {m['heldout_after_m'] * 100:.1f} cm, median over plans held out from it"
            if m["offered"]:
                on = ", ".join(m["fit"]["features"]) or "a constant offset"
                parts.append(f"a {LABEL} on {on} lowers the held-out {self.outcome} disparity ({figs})")
            else:
                parts.append(f"no gain from a data-driven residual model on held-out plans ({figs}): none offered")
        return "; ".join(parts)


def behaviour_features(ev: Any) -> tuple[list[str], np.ndarray]:
    """Per used trial, the task's behaviour features (names, (N, k)) from the plans and the nominal features of every
    group (NaN where the nominal rollout is unknown)."""
    full = ev.sim.full_cache.get(ev.sim.key({}))
    full = np.full_like(ev.y0, np.nan) if full is None else full
    return ev.model.behaviour_features(ev.plans, full)


def residual_report(ev: Any, prob: fitting.Problem, y_model: np.ndarray, folds: int, rng: np.random.Generator) -> ResidualReport:
    """Where the residual of ``y_model`` (the chosen model's features, N x F) lives and the held-out gain of the
    data-driven residual model on the outcomes (see the module docstring)."""
    sl = ev.model.slices()
    c2 = fitting.chi2_by_group(prob, y_model, sl)
    total = sum(c2.get(g, 0.0) for g in ev.measured_groups) or 1.0
    share = {g: float(c2.get(g, 0.0) / total) for g in ev.measured_groups}
    r = prob.weighted(y_model)
    rows = np.nonzero(prob.mask)[0]
    per = np.bincount(rows, weights=r * r, minlength=len(ev.used))
    worst = [{"trial": ev.used[i].trial, "plan": ev.plans[i].meta.get("name") or ev.plans[i].meta.get("generator", ""), "chi2": float(per[i])}
             for i in np.argsort(-per)[:3]]
    names, X = behaviour_features(ev)
    td = sl[ev.model.outcome]
    R = ev.y_meas[:, td] - y_model[:, td]
    ok = np.all(np.isfinite(X), axis=1) & np.all(np.isfinite(R), axis=1)
    return ResidualReport(share, worst, _follows(names, X[ok], R[ok]), _heldout(ev, names, X, R, ok, folds, rng), ev.model.outcome)


def _follows(names: list[str], X: np.ndarray, R: np.ndarray) -> list[dict]:
    """Behaviour features the outcome residual correlates with (Bonferroni over features x axes), strongest first."""
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
    """The cross-validated residual model on every usable trial, and its nested held-out gain (module docstring):
    offered only when the held-out outcome disparity, median and RMS over the held-out trials, is lower with it."""
    idx = np.nonzero(ok)[0]
    groups = np.array([ev.keys[i] for i in idx])
    n_plans = len(set(groups.tolist()))
    k = min(max(folds, HELDOUT_FOLDS), n_plans)
    if n_plans < max(k, 5):
        return {"label": LABEL, "offered": False, "better": False, "note": "too few distinct plans for a held-out gain"}
    before, after = nested_heldout(X[idx], R[idx], groups, k, rng, repeats=HELDOUT_REPEATS)
    done = np.isfinite(after)
    if not done.any():
        return {"label": LABEL, "offered": False, "better": False, "note": "no fold could be fitted"}
    model = ResidualModel().fit(X[idx], R[idx], groups)
    b, a = before[done], after[done]
    med_b, med_a = float(np.median(b)), float(np.median(a))
    rms_b, rms_a = float(np.sqrt(np.mean(b * b))), float(np.sqrt(np.mean(a * a)))
    better = bool(med_a < med_b and rms_a < rms_b and model.kind_ != "none")
    return {"label": LABEL, "features": names, "heldout_before_m": med_b, "heldout_after_m": med_a, "ratio_after_before": med_a / max(med_b, 1e-12),
            "heldout_rms_before_m": rms_b, "heldout_rms_after_m": rms_a, "n_heldout": int(done.sum()), "folds": k, "repeats": HELDOUT_REPEATS,
            "better": better, "offered": better, "fit": model.describe(names)}
