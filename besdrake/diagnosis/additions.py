"""What a log cannot exclude *beside* a named single cause: a second effect of the registry that the data allow on top
of it (the pair "named cause + that effect" is then as consistent with the log as the named cause alone).

Why (issue 25, touchdown-only logs): the parsimony step keeps a single effect when a pair adds nothing the data need,
and the rivals that are "the best plus an effect it does not need" are never listed. That is right when the log could
have shown the second effect; a log of a few numbers per trial mostly could not (benchmark, session 17: 9 touchdown-only
answers named one part of a hidden pair, the pair itself nowhere in the answer). Here each candidate effect is added to
the named cause on the linearised model around its fit: the named cause's parameters re-fitted with it (profile
likelihood, the fit's weak prior), one parameter of the added effect at a time (a realistic deviation moves one or two),
its allowed interval at level ALPHA within the realistic bounds; not excluded when a deviation of EXCLUDE_FRACTION of
its range is allowed, as for the nominal model (:mod:`~besdrake.diagnosis.allowed`). No rollouts: the added effect's
sensitivities are those at nominal (as the forward pairs use them), so a strongly nonlinear effect is judged roughly.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import stats

from besdrake.diagnosis import fitting
from besdrake.diagnosis import settings
from besdrake.diagnosis.allowed import allowed_range
from besdrake.diagnosis.settings import ALPHA, EXCLUDE_FRACTION, UNCONSTRAINED_COVER
from besdrake.diagnosis.stats import plan_of_entries, plan_scores


#: "Use the setting" for an argument whose None means "off" (:func:`listed`'s ``pair_dbic``).
SETTING = object()


@dataclass
class Addition:
    """One effect the log allows beside the named cause: per parameter the allowed interval (linearised, clipped to the
    realistic bounds), the largest allowed deviation as a fraction of the range, the chi-square the best of its
    parameters would gain (``gain``: the data's lean towards it) and whether the log constrains it at all."""

    effect: str
    allowed: dict[str, tuple[float, float]]
    units: dict[str, str]
    max_fraction: float
    gain: float
    unconstrained: bool
    #: per parameter: its allowed fraction of the range, chi-square gain, and the share of its signature the named cause's
    #: parameters absorb (1 - |a_perp|^2 / |a|^2; near 1: the cause takes it for a change of its own parameters)
    per_param: dict[str, dict[str, float]] | None = None

    @property
    def excluded(self) -> bool:
        return self.max_fraction < EXCLUDE_FRACTION

    def to_dict(self) -> dict:
        return {"effect": self.effect, "allowed": {k: [float(a), float(b)] for k, (a, b) in self.allowed.items()}, "units": dict(self.units),
                "max_allowed_fraction_of_range": self.max_fraction, "chi2_gain": self.gain, "unconstrained": self.unconstrained,
                "excluded": self.excluded, "per_param": self.per_param or {}}

    def describe(self) -> str:
        if self.unconstrained:
            return f"{self.effect} (any realistic value)"
        return f"{self.effect} (" + "; ".join(f"{k} {a:.3g}..{b:.3g} {self.units.get(k, '')}".rstrip() for k, (a, b) in self.allowed.items()) + ")"


def additions_beside(prob: fitting.Problem, sens: fitting.Sensitivity, best: fitting.CandidateFit, cands: Sequence[str],
                     keys: Sequence[str] | None = None) -> list[Addition]:
    """Per candidate effect not in ``best`` (a refined fit with a Jacobian at its optimum), what the log allows of it
    on top of ``best`` (see the module); sorted by the largest allowed fraction of the range. Per parameter also its
    signature on top of the cause (the chi-square it adds, linearised) at the estimate and at the farthest allowed end,
    and, with ``keys`` (the trials' plan keys), its score z with the plans as the units (:func:`_plan_z`)."""
    if best.y_fit is None or best.jac is None:
        return []
    q = float(stats.chi2.ppf(1.0 - ALPHA, 1))
    entry_key = None if keys is None else plan_of_entries(prob, keys)
    P_b, b_b = fitting._prior_rows(best.specs, best.theta)
    M = np.vstack([best.jac, P_b]) if best.specs else np.zeros((prob.n, 0))
    r = np.concatenate([prob.weighted(best.y_fit), b_b]) if best.specs else prob.weighted(best.y_fit)
    Q = np.linalg.qr(M)[0] if M.shape[1] else np.zeros((M.shape[0], 0))
    out = []
    for e in cands:
        if e in best.effects:
            continue
        cols = fitting.effect_columns(prob, sens, e)
        if cols is None:
            continue
        specs, A, P = cols
        allowed, units, fracs, gains, covers, per = {}, {}, [], [], [], {}
        for j, s_ in enumerate(specs):
            a = np.concatenate([A[:, j], np.zeros(M.shape[0] - prob.n)])
            a_perp = a - Q @ (Q.T @ a)  # the named cause's parameters re-fitted along with it
            info = float(a_perp @ a_perp) + float(P[j, j] ** 2)
            score = float(a_perp @ r)
            est = s_.nominal + score / info
            half = float(np.sqrt(q / info))
            lo, hi, frac = allowed_range(s_, est, max(s_.low, est - half), min(s_.high, est + half))
            rng_ = s_.high - s_.low
            fracs.append(frac)
            gains.append(score * score / info)
            covers.append(hi - lo >= UNCONSTRAINED_COVER * rng_)
            allowed[s_.name], units[s_.name] = (float(lo), float(hi)), s_.unit
            a2 = float(a @ a)
            ap2 = float(a_perp[:prob.n] @ a_perp[:prob.n])
            per[s_.name] = {"fraction": fracs[-1], "gain": gains[-1], "absorbed": 1.0 - float(a_perp @ a_perp) / a2 if a2 > 0 else 0.0,
                            "covers": bool(covers[-1]), "z": score / np.sqrt(info) if info > 0 else 0.0,
                            "signature_est": ap2 * (est - s_.nominal) ** 2,
                            "signature_max": ap2 * max(abs(lo - s_.nominal), abs(hi - s_.nominal)) ** 2,
                            "z_plans": _plan_z(a_perp[:prob.n], r[:prob.n], entry_key)}
        out.append(Addition(e, allowed, units, float(max(fracs)), float(max(gains)), all(covers), per))
    out.sort(key=lambda x: -x.max_fraction)
    return out


def _plan_z(a: np.ndarray, r: np.ndarray, entry_key: np.ndarray | None) -> float | None:
    """The score of the residuals ``r`` along ``a`` over the cluster-robust SD with the plans as the units (the per-plan
    scores' root sum of squares): the noise model is not trusted between plans (issue 25). None without the entries'
    plans (:func:`~besdrake.diagnosis.stats.plan_of_entries`)."""
    if entry_key is None:
        return None
    per = plan_scores(a, r, entry_key)
    den = float(np.sqrt(np.sum(per ** 2)))
    return float(per.sum() / den) if den > 0 else 0.0


def listed(additions: Sequence[dict], min_fraction: float | None = None, min_gain: float | None = None,
           unconstrained: bool | str | None = None, at_most: int | None = None, refined_dbic: dict[str, float] | None = None,
           pair_dbic: float | None | object = SETTING) -> list[str]:
    """The effects of :func:`additions_beside` (as dicts, :meth:`Addition.to_dict`) that the answer lists as "cannot
    tell whether it is present too": not excluded (allowed beyond ``min_fraction`` of the range) and either leaned
    towards by the data (the chi-square gain of its best parameter at least ``min_gain``) or not constrained by the log
    at all (``unconstrained``), or whose pair with the cause, fitted with rollouts, is within ``pair_dbic`` of it by BIC
    (``refined_dbic``: effect -> the pair's delta BIC; the rivals' "cannot tell" margin, without the exception for "the
    best plus an effect it does not need"); at most ``at_most``, the largest gain first. Thresholds default to the
    settings' ADDITION_MIN_FRACTION, ADDITION_MIN_GAIN, ADDITION_UNCONSTRAINED, ADDITIONS_MAX and ADDITION_PAIR_DBIC (a
    benchmark passes others; ``pair_dbic`` None: no refined pair listed for its BIC alone)."""
    min_fraction = settings.ADDITION_MIN_FRACTION if min_fraction is None else min_fraction
    min_gain = settings.ADDITION_MIN_GAIN if min_gain is None else min_gain
    unconstrained = settings.ADDITION_UNCONSTRAINED if unconstrained is None else unconstrained
    at_most = settings.ADDITIONS_MAX if at_most is None else at_most
    pair_dbic = settings.ADDITION_PAIR_DBIC if pair_dbic is SETTING else pair_dbic
    near = {e for e, d in (refined_dbic or {}).items() if pair_dbic is not None and d < pair_dbic}
    def free(a: dict) -> bool:  # "any": one of its parameters may be anywhere in its range beside the cause
        return bool(a["unconstrained"] if unconstrained != "any" else any(p["covers"] for p in a.get("per_param", {}).values()))

    ok = [a for a in additions if (a["max_allowed_fraction_of_range"] >= min_fraction
          and (a["chi2_gain"] >= min_gain or (unconstrained and free(a)))) or a["effect"] in near]
    ok.sort(key=lambda a: -a["chi2_gain"])
    return [a["effect"] for a in ok[:at_most]]


def aliases(additions: Sequence[dict], single_dbic: dict[str, float], max_dbic: float | None = None, min_absorbed: float | None = None) -> list[str]:
    """Near aliases of the named cause: the single effects, fitted with rollouts within ``max_dbic`` of it by BIC
    (``single_dbic``: effect -> delta BIC), one of whose parameters moves the signals (nearly) as a change of the
    cause's own parameters would (the share the cause absorbs, :func:`additions_beside`'s ``per_param``, at least
    ``min_absorbed``): the log cannot tell which of the two it is beyond that margin. Defaults: the settings'
    ALIAS_DBIC and ALIAS_ABSORBED (None: off)."""
    max_dbic = settings.ALIAS_DBIC if max_dbic is None else max_dbic
    min_absorbed = settings.ALIAS_ABSORBED if min_absorbed is None else min_absorbed
    if max_dbic is None or min_absorbed is None:
        return []
    absorbed = {a["effect"]: max((p["absorbed"] for p in a.get("per_param", {}).values()), default=0.0) for a in additions}
    return [e for e, d in sorted(single_dbic.items(), key=lambda x: x[1]) if d < max_dbic and absorbed.get(e, 0.0) >= min_absorbed]
