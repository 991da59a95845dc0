"""Whether the named cause's lead over its rivals stands whichever plan of the log is left out (a plan jackknife).

A lead resting on one plan is a lead that one unlucky trial can make: trial-to-trial scatter the model does not explain
moves a whole trial's features together (an outcome and the path that led to it), and the diagonal noise model counts
that one deviation in every feature, so a single trial drawn 3 SD off is worth tens of chi2 to an effect that mimics it
(issue 25, the diagnosis benchmark's seed 6, trial 42: an effect that is not there named beside the right one with
"high", one trial of 25 carrying 24 of the pair's 39 chi2 over the truth; without it the pair led its nearest rival by
1 BIC, not 14.5; the task's CALIBRATION.md, "A plan jackknife for high"). The refits without a plan are linearised at
each candidate's refined fit (one Gauss-Newton step on its weighted Jacobian with the fit's weak prior, no rollouts),
so the check costs a few small solves per candidate and plan.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from besdrake.diagnosis import fitting
from besdrake.diagnosis.noise import plan_rows


@dataclass
class JackknifeMargin:
    """The smallest BIC lead of the named cause over a rival with one plan left out: ``margin_dbic`` (inf: no rival
    could be refitted), the rival it is smallest against, and the left-out plan's trials (row indices of the log)."""

    margin_dbic: float
    rival: str | None = None
    left_out: tuple[int, ...] = ()

    def to_dict(self) -> dict:
        return {"jackknife_margin_dbic": None if not np.isfinite(self.margin_dbic) else float(self.margin_dbic),
                "jackknife_rival": self.rival, "jackknife_left_out": list(self.left_out)}


def left_out_bics(prob: fitting.Problem, fit: fitting.CandidateFit, plans: list[list[int]]) -> np.ndarray | None:
    """Per plan, ``fit``'s BIC on the log without that plan, refitted by one linearised step (None without a refined
    fit's simulated features)."""
    if fit.y_fit is None:
        return None
    r = prob.weighted(fit.y_fit)
    trial_of = np.nonzero(prob.mask)[0]
    J = fit.jac if fit.jac is not None and fit.jac.shape[0] == len(r) else np.zeros((len(r), 0))
    P = fitting._prior_rows(fit.specs, fit.theta)[0] if J.shape[1] else np.zeros((0, 0))
    out = np.empty(len(plans))
    for j, rows in enumerate(plans):
        keep = ~np.isin(trial_of, rows)
        rk, Jk = r[keep], J[keep]
        if Jk.shape[1]:
            step = np.linalg.lstsq(np.vstack([Jk, P]), np.concatenate([rk, np.zeros(len(P))]), rcond=None)[0]
            rk = rk - Jk @ step
        n = int(keep.sum())
        out[j] = float(rk @ rk) + fit.k_eff * np.log(max(n, 1)) + fit.selection_penalty
    return out


def jackknife_margin(prob: fitting.Problem, named: fitting.CandidateFit, rivals: list[fitting.CandidateFit],
                     keys: list[str]) -> JackknifeMargin:
    """The named cause's smallest BIC lead over ``rivals`` with one plan of the log left out (rivals without a refined
    fit are skipped; a log of fewer than three plans is not jackknifed)."""
    plans = plan_rows(keys)
    own = left_out_bics(prob, named, plans) if len(plans) >= 3 else None
    best = JackknifeMargin(float("inf"))
    if own is None:
        return best
    for f in rivals:
        theirs = left_out_bics(prob, f, plans)
        if theirs is None:
            continue
        lead = theirs - own
        j = int(np.argmin(lead))
        if lead[j] < best.margin_dbic:
            best = JackknifeMargin(float(lead[j]), f.name, tuple(plans[j]))
    return best


__all__ = ["JackknifeMargin", "jackknife_margin", "left_out_bics", "plan_rows"]
