"""The gain of a refined model on trials held out from its fit, and the per-trial table of a diagnosis."""

from __future__ import annotations

from typing import Any

import numpy as np

from besdrake.diagnosis import fitting, settings
from besdrake.diagnosis.results import Gain
from besdrake.diagnosis.stats import _bootstrap_median_ci


def heldout_gain(ev: Any, sens: fitting.Sensitivity, best_fit: fitting.CandidateFit, best_shift, folds: int, iterations: int,
                 rng: np.random.Generator) -> tuple[Gain | None, np.ndarray]:
    """Outcome disparity before/after on trials held out from the fit (K-fold by plan: repeats of a plan stay together,
    so a held-out plan was never seen by the fit), and the per-trial held-out disparity after (NaN where none)."""
    td = ev.model.slices()[ev.model.outcome]
    y_meas, y0 = ev.y_meas, ev.y0
    per_trial_after = np.full(len(ev.used), np.nan)
    have_td = np.isfinite(y_meas[:, td]).all(axis=1) & np.isfinite(y0[:, td]).all(axis=1)
    gain = None
    if best_fit.effects and have_td.sum() >= folds >= 2:
        idx = np.nonzero(have_td)[0]
        uniq = sorted(set(ev.keys[i] for i in idx))
        order = rng.permutation(len(uniq))
        fold_of = {uniq[j]: r % folds for r, j in enumerate(order)}
        for k in range(folds):
            test = [i for i in idx if fold_of[ev.keys[i]] == k]
            train = [i for i in range(len(ev.used)) if fold_of.get(ev.keys[i], -1) != k]
            if test and len(train) >= 3:
                per_trial_after[test] = _fold_disparity(ev, sens, best_fit, best_shift, train, test, iterations)
        before = np.linalg.norm(y_meas[:, td] - y0[:, td], axis=1)
        ok = np.isfinite(per_trial_after) & have_td
        b, a = before[ok], per_trial_after[ok]
        if len(a):
            gain = Gain(float(np.median(b)), float(np.median(a)), _bootstrap_median_ci(b, rng), _bootstrap_median_ci(a, rng),
                        float(np.median(a) / max(np.median(b), 1e-12)), int(len(a)), folds, b.tolist(), a.tolist())
    if gain is None and have_td.sum() >= 1 and not best_fit.effects:
        # Nothing to refine: the refined model is the nominal one, before = after.
        b = np.linalg.norm(y_meas[have_td][:, td] - y0[have_td][:, td], axis=1)
        ci = _bootstrap_median_ci(b, rng)
        gain = Gain(float(np.median(b)), float(np.median(b)), ci, ci, 1.0, int(len(b)), 0, b.tolist(), b.tolist())
    return gain, per_trial_after


def _fold_disparity(ev: Any, sens: fitting.Sensitivity, best_fit: fitting.CandidateFit, best_shift, train: list[int], test: list[int],
                    iterations: int) -> np.ndarray:
    """Outcome disparity of the ``test`` trials under the best cause refitted on the ``train`` trials only: warm
    start at the all-data optimum (its simulated features of the training trials are known, or simulated where the fold's
    parameter selection dropped a parameter the optimum moved: :func:`~besdrake.diagnosis.fitting.warm_start`), then Gauss-Newton."""
    td = ev.model.slices()[ev.model.outcome]
    sim = ev.sim
    prob_k = fitting.Problem(ev.y_meas, ev.y0, ev.nm.matrix(len(ev.y_meas)), rows=train, cov=ev.nm.covariances(len(ev.y_meas)))
    fit_k = fitting.linear_fit(prob_k, sens, best_fit.effects, select=settings.SELECT_PARAMETERS)

    def simulate(effects: dict) -> np.ndarray:
        return sim.one(effects, rows=train, shift=best_shift)

    starts = [fitting.warm_start(fit_k.specs, best_fit, simulate)] if best_fit.y_fit is not None else []
    fitting.refine(prob_k, fit_k, simulate, iterations=iterations, starts=starts, try_linear=False)
    y_test = sim.one(fit_k.parameters(), rows=test, shift=best_shift)
    return np.linalg.norm(ev.y_meas[test][:, td] - y_test[test][:, td], axis=1)


def per_trial_table(ev: Any, y_best: np.ndarray, per_trial_after: np.ndarray) -> list[dict[str, Any]]:
    """One row per used trial: errors per group before and after the fit, outcomes, held-out disparity, and the task's
    details (:meth:`~besdrake.diagnosis.trials.TrialModel.trial_details`) of the lab, the nominal and the refined
    simulation."""
    model = ev.model
    sl, out = model.slices(), model.outcome
    td = sl[out]
    y_meas, y0 = ev.y_meas, ev.y0
    rows = []
    for i, m in enumerate(ev.used):
        row: dict[str, Any] = {"trial": m.trial, "plan": m.plan.meta.get("name") or m.plan.meta.get("generator", ""), "plan_hash": ev.keys[i][:12]}
        for g, s in sl.items():
            if np.isfinite(y_meas[i, s]).all():
                row[f"{g}_error_before"] = float(np.linalg.norm(y_meas[i, s] - y0[i, s]))
                row[f"{g}_error_after_fit"] = float(np.linalg.norm(y_meas[i, s] - y_best[i, s]))
        row[f"{out}_measured"] = None if not np.isfinite(y_meas[i, td]).all() else y_meas[i, td].tolist()
        row[f"{out}_nominal"] = y0[i, td].tolist()
        row[f"{out}_refined"] = y_best[i, td].tolist()
        row[f"{out}_heldout_disparity_after"] = None if not np.isfinite(per_trial_after[i]) else float(per_trial_after[i])
        for label, y in (("lab", y_meas[i]), ("nominal", y0[i]), ("refined", y_best[i])):
            for k, v in model.trial_details(y, ev.layouts[i], ev.plans[i]).items():
                row[f"{k}_{label}"] = v
        rows.append(row)
    return rows
