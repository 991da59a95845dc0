"""``diagnose(measurements)``: what the simulation gets wrong, the cause, the refined model and the gain.

1. *Comparison*: every usable logged plan is replayed in the nominal simulation and compared throw by throw
   (touchdown, the ball's flight state, joint tracking, the ball at rest in the scoop;
   :mod:`~besdrake.diagnosis.observables`); the mean
   residual of each group is tested against the measurement noise (systematic vs noise). A simulated throw is the
   *expected* throw of a lab whose ball placement scatters (``placement_sd``, :func:`placement_points`): the throw is
   nonlinear in the placement, so the scatter shifts the mean and would otherwise be taken for an effect.
2. *Cause*: every candidate effect of the registry and every pair is fitted (:mod:`~besdrake.diagnosis.fitting`)
   and ranked by BIC (the leading candidates with the placement correction recomputed at their own parameters,
   :meth:`_Sim.local_shift`; a pair's second effect claimed only if it is significant with the throws' plans as the
   independent units, :func:`_extra_effect_significant`, since residuals within a throw are strongly correlated and
   BIC over entries counts one throw's noise several times; an effect that hardly moves the predictions is dropped
   unless it alone is :data:`STRONG_DBIC` better than nominal); candidates within :data:`INDISTINGUISHABLE_DBIC` of the best that are not merely the
   best plus an unneeded effect are reported as "cannot tell apart", with the recording or throw that would
   separate them (predicted by simulating both fitted candidates). When even the best candidate leaves a
   residual above the noise (lack-of-fit test at :data:`ALPHA`), the result is "not explained". When no candidate
   improves significantly on the nominal simulation, the answer is "no discrepancy beyond the noise" together with
   the effects the log cannot exclude and the magnitudes it still allows (``cannot_tell``; ``unconstrained`` marks
   those of which any realistic value fits, apart from those a larger deviation would have shown), never a confident
   "the nominal model is right". A cause named from touchdowns alone is never reported with high confidence.
3. *Refined model*: the scenario with the fitted effects (:meth:`Diagnosis.refined_scenario`).
4. *Gain*: touchdown disparity before/after on throws held out from the fit (K-fold: each throw is predicted
   by a model fitted without it), medians with bootstrap confidence intervals.
"""

from __future__ import annotations

import time
from typing import Sequence

import numpy as np

from besdrake.diagnosis import fitting, observables
from besdrake.diagnosis.advice import _RECORD, _separation_advice  # noqa: F401  (re-exported)
from besdrake.diagnosis.allowed import _Line, _allowed_effects, _verify_interval_ends  # noqa: F401
from besdrake.diagnosis.heldout import heldout_gain, per_throw_table
from besdrake.diagnosis.identifiability import Identifiability, structural_classes
from besdrake.diagnosis.replay import Evidence, compare, fit_linear, replay
from besdrake.diagnosis.residual import residual_report
from besdrake.diagnosis.results import AllowedEffect, Cause, Diagnosis, DiagnosisError, Gain, GroupComparison  # noqa: F401
from besdrake.diagnosis.selection import _forward_pairs, parsimony, refine_leaders, refine_rivals  # noqa: F401
from besdrake.diagnosis.settings import *  # noqa: F401,F403  (the thresholds, as before the split)
from besdrake.diagnosis.settings import ALPHA, EXCLUDE_FRACTION, INDISTINGUISHABLE_DBIC, MIN_THROWS, PLACEMENT_SD
from besdrake.diagnosis.simulate import _full_layout, _placement_correction, _Sim, placement_points  # noqa: F401
from besdrake.diagnosis.stats import _bootstrap_median_ci, _extra_effect_significant, _lack_of_fit_p, _material_change  # noqa: F401
from besdrake.diagnosis.verdict import judge, rank_causes
from besdrake.sim.effects import list_effects
from besdrake.sim.scenario import Scenario, load_scenario


def diagnose(
    measurements: Sequence,
    scenario: Scenario | str = "nominal",
    candidates: Sequence[str] | None = None,
    pairs: bool = True,
    backend: str = "serial",
    workers: int | None = None,
    folds: int = 3,
    refine_top: int = 3,
    refine_iterations: int = 5,
    seed: int = 0,
    executor=None,
    cache: dict | None = None,
    placement_sd: float = PLACEMENT_SD,
    structural: bool = True,
) -> Diagnosis:
    """Diagnose a lab log (a list of :class:`~besdrake.transfer.measurement.Measurement`).

    ``candidates``: effect names to consider (default: every registered effect); ``pairs``: also fit every
    pair; ``backend``/``workers``: the rollout executor (:func:`besdrake.sim.make_executor`), or pass an
    open ``executor``; ``folds``: K of the held-out (K-fold) gain; ``seed`` seeds the bootstrap and folds;
    ``cache``: a dict memoising Outcomes by (plan hash, effects), shareable between diagnoses of the same
    scenario (never between scenarios); ``placement_sd``: the lab's throw-to-throw scatter of the ball's placement
    in the scoop (m per axis, default :data:`PLACEMENT_SD`): every simulated throw is compared as the mean over
    that scatter (:func:`_placement_correction`; 0: the ball always centred); ``structural``: find the candidate
    parameters no experiment separates (:func:`besdrake.diagnosis.identifiability.structural_classes`, cached as JSON
    per registry and scenario) and state them as such.
    """
    from besdrake.sim.executors import make_executor
    from besdrake.transfer.measurement import plan_hash

    t_start = time.perf_counter()
    scen, cands = _check_inputs(scenario, candidates, placement_sd)
    measurements = list(measurements)
    used, skipped = _split_usable(measurements)
    keys = [plan_hash(m.plan) for m in used]
    own_executor = executor is None
    ex = executor or make_executor(backend, workers=workers, scenario=scen, limits="flag")
    try:
        timings: dict[str, float] = {}
        ev = replay(used, keys, ex, cache, scen, placement_sd)
        timings["replay"] = time.perf_counter() - t_start
        ident = structural_classes(cands, scen, executor=ex) if structural else None
        timings["identifiability"] = time.perf_counter() - t_start - timings["replay"]
        d = _diagnose_evidence(ev, cands, pairs, folds, refine_top, refine_iterations, np.random.default_rng(seed), placement_sd, timings, ident)
    finally:
        if own_executor:
            ex.close()
    d.n_trials, d.skipped, d.scenario = len(measurements), skipped, scen
    d.timings["total"] = time.perf_counter() - t_start
    return d


def _check_inputs(scenario: Scenario | str, candidates: Sequence[str] | None, placement_sd: float) -> tuple[Scenario, list[str]]:
    """The scenario and the candidate effects; :class:`DiagnosisError` for unknown candidates or a bad placement scatter."""
    scen = load_scenario(scenario) if not isinstance(scenario, Scenario) else scenario
    known = list_effects()
    cands = list(known if candidates is None else candidates)
    unknown = [c for c in cands if c not in known]
    if unknown:
        raise DiagnosisError(f"unknown candidate effect(s) {unknown}; registered effects: {known}")
    if not cands:
        raise DiagnosisError("no candidate effects to fit")
    if not (np.isfinite(placement_sd) and 0.0 <= placement_sd <= 0.008):
        raise DiagnosisError(f"placement_sd must be within 0..0.008 m (the scoop's placement range), got {placement_sd!r}")
    return scen, cands


def _split_usable(measurements: list) -> tuple[list, list[dict]]:
    """The usable throws and the skipped ones (trial and reason); :class:`DiagnosisError` below MIN_THROWS."""
    used, skipped = [], []
    for m in measurements:
        ok, why = observables.usable(m)
        (used if ok else skipped).append(m if ok else {"trial": m.trial, "reason": why})
    if len(used) < MIN_THROWS:
        raise DiagnosisError(f"only {len(used)} usable throws in the log ({len(skipped)} skipped); the diagnosis needs at least {MIN_THROWS}")
    return used, skipped


def _diagnose_evidence(ev: Evidence, cands: list[str], pairs: bool, folds: int, refine_top: int, iterations: int, rng: np.random.Generator,
                       placement_sd: float, timings: dict[str, float], ident: Identifiability | None = None) -> Diagnosis:
    """Steps 2-4 on the replayed log: fit the candidates, choose and judge the cause, measure the held-out gain."""
    comparison = compare(ev)
    t0 = time.perf_counter()
    specs, spec_notes = fitting.param_specs(cands)
    sens = fitting.compute_sensitivity(specs, ev.y0, lambda effs: ev.sim.features(effs))
    timings["sensitivity"] = time.perf_counter() - t0
    prob, fits = fit_linear(ev, sens, cands, pairs)
    notes = list(ev.nm.notes) + spec_notes + _placement_note(ev, placement_sd)
    t0 = time.perf_counter()
    local_shift = refine_leaders(prob, fits, sens, ev.sim, ev.nm, ev.measured_groups, pairs, refine_top, iterations)
    none_fit = next(f for f in fits if not f.effects)
    none_fit.refined, none_fit.y_fit = True, ev.y0
    timings["refine"] = time.perf_counter() - t0
    # Rank: refined candidates by their real chi2; linear-only ones are never ranked above a refined one
    # with a better linear BIC (they were not refined because their linear fit was worse).
    fits.sort(key=lambda f: (f.bic if f.refined else np.inf, f.bic))
    best_fit = parsimony(prob, fits, ev.nm, ev.measured_groups, cands, ev.keys, notes)
    refine_rivals(prob, fits, best_fit, ev.sim, ev.measured_groups, iterations)
    best_shift = local_shift.get(best_fit.effects)
    fitting.jacobian_at(prob, best_fit, lambda effs: ev.sim.features(effs, shift=best_shift))
    causes = rank_causes(prob, fits, best_fit, ev.nm, ev.measured_groups)
    v = judge(prob, sens, fits, causes, ev, cands, ident)
    t0 = time.perf_counter()
    gain, per_throw_after = heldout_gain(ev, sens, v.best_fit, best_shift, folds, iterations, rng)
    timings["heldout"] = time.perf_counter() - t0
    y_best = v.best_fit.y_fit if v.best_fit.y_fit is not None else ev.y0
    per_throw = per_throw_table(ev, y_best, per_throw_after)
    residual = None
    if not v.explained:  # still "not explained"; beside it, where the residual lives and a data-driven model of it
        rep = residual_report(ev, prob, y_best, folds, rng)
        residual = rep.to_dict()
        v.text += "; " + rep.describe()
    if ev.mocap_sd is not None:
        notes.append(f"marker noise from the flight fits: {ev.mocap_sd * 1000:.1f} mm")
    if ev.enc_sd is not None:
        notes.append(f"encoder noise from second differences: {ev.enc_sd:.2e} rad")
    return Diagnosis(
        explained=v.explained, confidence=v.confidence, verdict=v.text, causes=v.causes, best=v.best, indistinguishable=v.indist, noise=ev.nm,
        comparison=comparison, gain=gain, groups_measured=ev.measured_groups, n_trials=len(ev.used), n_used=len(ev.used), skipped=[], per_throw=per_throw,
        scenario=None, timings=timings, n_rollouts=ev.sim.n_rollouts, notes=notes, cannot_tell=v.cannot_tell, excluded=v.excluded,
        structural=[{"members": c.members, "reason": c.statement()} for c in ident.classes] if ident is not None else [], residual=residual,
    )


def _placement_note(ev: Evidence, placement_sd: float) -> list[str]:
    if not ev.placement_summary:
        return []
    return [f"every simulated throw is the mean over the ball's placement scatter ({placement_sd * 1000:g} mm SD per axis, "
            f"{len(placement_points(placement_sd))} placements); mean correction per group: " + ", ".join(f"{g} {v}" for g, v in ev.placement_summary.items())]


__all__ = ["diagnose", "Diagnosis", "Cause", "Gain", "AllowedEffect", "EXCLUDE_FRACTION", "GroupComparison", "DiagnosisError", "ALPHA", "INDISTINGUISHABLE_DBIC"]
