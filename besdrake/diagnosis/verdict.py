"""The verdict of a diagnosis: ranked causes, rivals the log cannot tell apart, confidence, and the sentence."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


from besdrake.diagnosis import fitting, noise
from besdrake.diagnosis.advice import _separation_advice
from besdrake.diagnosis.identifiability import Identifiability, StructuralClass
from besdrake.diagnosis.allowed import _allowed_effects
from besdrake.diagnosis.results import AllowedEffect, Cause
from besdrake.diagnosis import settings
from besdrake.diagnosis.settings import ALPHA, CONFIDENT_P, EXCLUDE_FRACTION, HIGH_MARGIN_DBIC, INDISTINGUISHABLE_DBIC
from besdrake.diagnosis.stats import _lack_of_fit_p
from besdrake.sim.effects import get_effect


@dataclass
class Verdict:
    """What :func:`judge` decided (``fits``/``causes`` ranked as reported, the chosen one first)."""

    explained: bool
    confidence: str
    text: str
    causes: list[Cause]
    fits: list[fitting.CandidateFit]
    best: Cause
    best_fit: fitting.CandidateFit
    indist: list[dict]
    cannot_tell: list[AllowedEffect] = field(default_factory=list)
    excluded: list[AllowedEffect] = field(default_factory=list)


def rank_causes(prob: fitting.Problem, fits: list[fitting.CandidateFit], best_fit: fitting.CandidateFit, nm: noise.NoiseModel,
                groups: list[str]) -> list[Cause]:
    """A :class:`Cause` per fit (in the order of ``fits``), with the lack-of-fit p-values of the refined ones."""
    causes = []
    for f in fits:
        if f.refined:
            p, p_groups = _lack_of_fit_p(prob, f.y_fit, f.k, nm, groups)
        else:
            p, p_groups = float("nan"), {}
        causes.append(Cause(f.effects, f.parameter_table(), f.bic, f.bic - best_fit.bic, f.chi2, f.n, f.k, f.refined, p, f.unobservable, p_groups, f.k_eff,
                            list(f.inactive), f.selection_penalty))
    return causes


def cause_keys(cause: Cause, z: float = 2.0) -> list[str]:
    """The ``effect.param`` keys a cause actually moves: fitted more than ``z`` standard errors from nominal (all its
    fitted parameters when none is)."""
    keys, moved = [], []
    for p in cause.parameters:
        key = f"{p['effect']}.{p['parameter']}"
        keys.append(key)
        nominal = get_effect(p["effect"]).params[p["parameter"]].nominal
        se = p.get("stderr")
        if se is None or not np.isfinite(se) or abs(p["value"] - nominal) > z * se:
            moved.append(key)
    return moved or keys


def structural_rival(best: Cause, rival: Cause, ident: Identifiability | None) -> StructuralClass | None:
    """The structural class that makes ``rival`` the same cause as ``best`` (None: they differ, or not known)."""
    if ident is None or not best.effects or not rival.effects:
        return None
    return ident.identical(cause_keys(best), cause_keys(rival))


def indistinguishable(fits: list[fitting.CandidateFit], causes: list[Cause], ev: Any, ident: Identifiability | None = None) -> list[dict]:
    """Refined rivals about as likely as the best (|delta chi2| < threshold, whatever the parameter count) or as good by
    BIC, that are not merely the best plus an effect it does not need, each with what would separate it, or, for a
    rival structurally identical to the best (:mod:`~besdrake.diagnosis.identifiability`), why nothing would
    (``structural``: True, no experiment suggested)."""
    best, indist = causes[0], []
    for f, c in zip(fits[1:], causes[1:]):
        same_likelihood = abs(c.chi2 - best.chi2) < INDISTINGUISHABLE_DBIC
        if not f.refined or not c.effects or not (c.delta_bic < INDISTINGUISHABLE_DBIC or same_likelihood):
            continue
        if set(best.effects) <= set(c.effects):
            continue  # the best plus an effect it does not need
        cls = structural_rival(best, c, ident)
        if cls is not None:
            adv = {"a": fits[0].name, "b": f.name, "structural": True, "reason": cls.statement(), "members": list(cls.members),
                   "recommendation": "none: " + cls.statement()}
        else:
            adv = _separation_advice(fits[0], f, ev.sim, ev.measured_groups, [p.meta for p in ev.plans])
            adv["structural"] = False
        adv["delta_bic"] = c.delta_bic
        indist.append(adv)
    return indist


def _clear_margin(fits: list[fitting.CandidateFit], causes: list[Cause], indist: list[dict]) -> bool:
    """The best cause leads every refined rival (the nominal model included) that is not merely the best plus an
    unneeded effect, nor structurally the same cause, by at least HIGH_MARGIN_DBIC (always true when switched off)."""
    if not settings.VERIFY_SINGLES:
        return True
    best = causes[0]
    same = {a["b"] for a in indist if a.get("structural")}
    for f, c in zip(fits[1:], causes[1:]):
        if f.refined and not set(best.effects) <= set(c.effects) and f.name not in same and c.delta_bic < HIGH_MARGIN_DBIC:
            return False
    return True


def judge(prob: fitting.Problem, sens: fitting.Sensitivity, fits: list[fitting.CandidateFit], causes: list[Cause], ev: Any,
          cands: list[str], ident: Identifiability | None = None) -> Verdict:
    """Explained or not, with what confidence, and why (see :class:`~besdrake.diagnosis.results.Diagnosis`). A rival
    structurally identical to the best (``ident``) is stated as such and does not lower the confidence: the answer is
    the class, and either fix gives the same robot."""
    best, best_fit = causes[0], fits[0]
    none_c = next(c for c in causes if not c.effects)
    indist = indistinguishable(fits, causes, ev, ident)
    separable = [a for a in indist if not a.get("structural")]
    outcome_only = set(ev.measured_groups) <= {ev.model.outcome}
    explained = bool(best.effects) and best.p_value >= ALPHA
    # An outcome-only log cannot vouch for the cause: the lack-of-fit test, the only guard against an effect the
    # registry does not know, has no power on a few numbers per trial (benchmark seed 0: all 5 unknown effects passed
    # it; a cross wind was taken for a base offset, 8.6 BIC ahead of the next candidate).
    confidence = ("high" if explained and not separable and best.p_value >= CONFIDENT_P and not outcome_only and _clear_margin(fits, causes, indist)
                  else "low")
    v = Verdict(explained, confidence, "", causes, fits, best, best_fit, indist)
    if not best.effects or (none_c.p_value >= ALPHA and none_c.delta_bic < INDISTINGUISHABLE_DBIC):
        _nothing_wrong(v, prob, sens, none_c, ev, cands)
    elif not explained:
        v.text = (f"not explained: the best candidate ({fits[0].name}) leaves a residual above the noise "
                  f"(lack-of-fit p = {best.p_value:.2g} < {ALPHA}); an effect the registry does not know is likely")
    elif separable:
        v.text = f"explained by {fits[0].name}, but cannot tell it from " + ", ".join(a["b"] for a in separable)
    else:
        v.text = f"explained by {fits[0].name} (next candidate {causes[1].delta_bic:.1f} BIC worse)"
    if v.best.effects and ident is not None:
        # The named cause moves a parameter that has a structural twin: say so whether or not the twin was a rival
        # (e.g. joint_offset with joint 1 named while the pair with a base yaw was dropped as not needed).
        keys = set(cause_keys(v.best))
        twins = [c.statement() for c in ident.classes if set(c.members) & keys and {m.split(".")[0] for m in c.members} <= set(cands)]
        twins += [a["reason"] for a in v.indist if a.get("structural")]
        if twins:
            v.text += "; " + "; ".join(dict.fromkeys(twins))
    if v.explained and v.best.effects and outcome_only:
        v.text += "; " + ev.model.outcome_only_note()
    if not v.explained and separable:
        v.text += "; candidates that fit about equally: " + ", ".join(a["b"] for a in separable)
    return v


def _nothing_wrong(v: Verdict, prob: fitting.Problem, sens: fitting.Sensitivity, none_c: Cause, ev: Any, cands: list[str]) -> None:
    """No candidate improves significantly on the nominal simulation. That is NOT evidence that the nominal model is
    right: say which effects (and how large) the data still allow; the nominal model is put first."""
    allowed = _allowed_effects(prob, sens, cands, ev.sim, ev.measured_groups, len(ev.used))
    v.cannot_tell = sorted([a for a in allowed if not a.excluded], key=lambda a: -a.max_fraction)
    v.excluded = [a for a in allowed if a.excluded]
    v.explained = True
    v.confidence = "high" if none_c.p_value >= CONFIDENT_P and not v.cannot_tell else "low"
    v.text = _cannot_tell_text(v.cannot_tell, v.excluded)
    if v.best.effects and none_c.p_value >= ALPHA:
        # The BIC-best candidate is not significantly better than nominal: it is named, not claimed (the refined
        # scenario stays nominal and the ranked causes start with the nominal model).
        what = ", ".join(f"{p_['effect']}.{p_['parameter']} = {p_['value']:.3g} {p_['unit']}" for p_ in v.best.parameters)
        v.text += (f"; the best-fitting candidate, {v.fits[0].name} ({what}), is not significantly better than the nominal "
                   f"simulation (delta BIC {none_c.delta_bic:.1f} < {INDISTINGUISHABLE_DBIC:g}) and is not claimed")
        j = v.causes.index(none_c)
        v.causes.insert(0, v.causes.pop(j))
        v.fits.insert(0, v.fits.pop(j))
        v.best, v.best_fit, v.indist = none_c, v.fits[0], []
    if none_c.p_value < ALPHA:
        v.explained, v.confidence, v.cannot_tell, v.excluded = False, "low", [], []
        v.text = ("not explained: the simulation differs from the lab beyond the noise, but no candidate effect changes the "
                  "predicted outcomes materially")


def _cannot_tell_text(cannot_tell: list[AllowedEffect], excluded: list[AllowedEffect]) -> str:
    """"no discrepancy beyond the noise, but the log cannot tell the nominal simulation from ..." (or all excluded)."""
    if not cannot_tell:
        return (f"the nominal simulation agrees with the lab within the measurement noise; every candidate effect is excluded "
                f"beyond {EXCLUDE_FRACTION:.0%} of its realistic range")
    bounded = [a for a in cannot_tell if not a.unconstrained]
    free = [a for a in cannot_tell if a.unconstrained]
    return ("no discrepancy beyond the measurement noise, but the log cannot tell the nominal simulation from "
            + (", ".join(a.describe() for a in bounded) + " (larger deviations would have been seen)" if bounded else "")
            + ("; " if bounded and free else "")
            + ("nor from " if bounded and free else "")
            + (", ".join(a.effect for a in free) + " at (nearly) any realistic magnitude (the logged signals do not constrain them)" if free else "")
            + (f"; excluded beyond {EXCLUDE_FRACTION:.0%} of their range: " + ", ".join(a.effect for a in excluded) if excluded else ""))
