"""``diagnose(measurements)``: what the simulation gets wrong, the cause, the refined model and the gain.

The engine is generic over *trials* (a logged plan and its measurement); the task says what a trial shows through
its :class:`~besdrake.diagnosis.trials.TrialModel` (:meth:`besdrake.task.Task.diagnosis_model`).

1. *Comparison*: every usable logged plan is replayed in the nominal simulation and compared trial by trial (the
   task's observable groups, e.g. an outcome, an object's path, joint tracking); the mean residual of each group is
   tested against the measurement noise (systematic vs noise). Where the lab's placement of an object scatters
   (``placement_sd``, the task's :class:`~besdrake.diagnosis.trials.PlacementScatter`), a simulated trial is the
   *expected* trial over that scatter: a trial nonlinear in the placement has its mean shifted by the scatter, which
   would otherwise be taken for an effect.
2. *Cause*: every candidate effect of the registry and every pair is fitted (:mod:`~besdrake.diagnosis.fitting`)
   and ranked by BIC (the leading candidates with the placement correction recomputed at their own parameters,
   :meth:`_Sim.local_shift`; a pair's second effect claimed only if it is significant with the trials' plans as the
   independent units, :func:`_extra_effect_significant`, since residuals within a trial are strongly correlated and
   BIC over entries counts one trial's noise several times; an effect that hardly moves the predictions is dropped
   unless it alone is :data:`STRONG_DBIC` better than nominal, and so is a parameter of the named cause,
   :mod:`~besdrake.diagnosis.parameters`); candidates within :data:`INDISTINGUISHABLE_DBIC` of
   the best that are not merely the best plus an unneeded effect are reported as "cannot tell apart", with the
   recording or trial that would separate them (predicted by simulating both fitted candidates). When even the best
   candidate leaves a residual above the noise (lack-of-fit test at :data:`ALPHA`), the result is "not explained".
   When no candidate improves significantly on the nominal simulation, the answer is "no discrepancy beyond the
   noise" together with the effects the log cannot exclude and the magnitudes it still allows (``cannot_tell``;
   ``unconstrained`` marks those of which any realistic value fits, apart from those a larger deviation would have
   shown), never a confident "the nominal model is right". A cause named from outcomes alone is never reported with
   high confidence.
3. *Refined model*: the scenario with the fitted effects (:meth:`Diagnosis.refined_scenario`).
4. *Gain*: outcome disparity before/after on trials held out from the fit (K-fold: each trial is predicted by a
   model fitted without it), medians with bootstrap confidence intervals.
"""

from __future__ import annotations

import time
from collections import Counter
from typing import Sequence

import numpy as np

from besdrake.diagnosis import fitting, settings
from besdrake.diagnosis.advice import _separation_advice  # noqa: F401  (re-exported)
from besdrake.diagnosis.allowed import _Line, _allowed_effects, _verify_interval_ends  # noqa: F401
from besdrake.diagnosis.heldout import heldout_gain, per_trial_table
from besdrake.diagnosis.identifiability import Identifiability, structural_classes
from besdrake.diagnosis.parameters import prune_parameters
from besdrake.diagnosis.replay import Evidence, compare, fit_linear, replay
from besdrake.diagnosis.residual import residual_report
from besdrake.diagnosis.results import AllowedEffect, Cause, Diagnosis, DiagnosisError, Gain, GroupComparison  # noqa: F401
from besdrake.diagnosis.selection import _forward_pairs, parsimony, rank, refine_leaders, refine_rivals, settle  # noqa: F401
from besdrake.diagnosis.settings import *  # noqa: F401,F403  (the thresholds, as before the split)
from besdrake.diagnosis.settings import ALPHA, EXCLUDE_FRACTION, INDISTINGUISHABLE_DBIC, MATERIAL, MIN_TRIALS
from besdrake.diagnosis.simulate import _placement_correction, _Sim  # noqa: F401
from besdrake.diagnosis.trials import TrialModel, model_for
from besdrake.diagnosis.stats import _bootstrap_median_ci, _extra_effect_significant, _lack_of_fit_p, _material_change  # noqa: F401
from besdrake.diagnosis.verdict import Verdict, judge, name_second_effect_shift, rank_causes, rivals_beating
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
    placement_sd: float | None = None,
    structural: bool = True,
) -> Diagnosis:
    """Diagnose a lab log (a list of :class:`~besdrake.transfer.measurement.Measurement`) of the scenario's task.

    ``candidates``: effect names to consider (default: the registry's effects that act on the scenario's task,
    :func:`besdrake.task.effects_for`); ``pairs``: also fit every
    pair; ``backend``/``workers``: the rollout executor (:func:`besdrake.sim.make_executor`), or pass an
    open ``executor``; ``folds``: K of the held-out (K-fold) gain; ``seed`` seeds the bootstrap and folds;
    ``cache``: a dict memoising Outcomes by (plan hash, effects), shareable between diagnoses of the same
    scenario (never between scenarios); ``placement_sd``: the lab's trial-to-trial scatter of the task's placement
    (m per axis, default the task's :attr:`~besdrake.diagnosis.trials.PlacementScatter.default_sd`): every simulated
    trial is compared as the mean over that scatter (:func:`_placement_correction`; 0: always centred); ``structural``: find the candidate
    parameters no experiment separates (:func:`besdrake.diagnosis.identifiability.structural_classes`, cached as JSON
    per registry and scenario) and state them as such.
    """
    from besdrake.sim.executors import make_executor
    from besdrake.transfer.measurement import plan_hash

    t_start = time.perf_counter()
    scen, cands, model, placement_sd = _check_inputs(scenario, candidates, placement_sd)
    measurements = list(measurements)
    used, skipped = _split_usable(measurements, model)
    keys = [plan_hash(m.plan) for m in used]
    own_executor = executor is None
    ex = executor or make_executor(backend, workers=workers, scenario=scen, limits="flag")
    try:
        timings: dict[str, float] = {}
        ev = replay(used, keys, ex, cache, scen, placement_sd, model)
        timings["replay"] = time.perf_counter() - t_start
        ident = structural_classes(cands, scen, executor=ex, model=model) if structural else None
        timings["identifiability"] = time.perf_counter() - t_start - timings["replay"]
        d = _diagnose_evidence(ev, cands, pairs, folds, refine_top, refine_iterations, np.random.default_rng(seed), placement_sd, timings, ident)
    finally:
        if own_executor:
            ex.close()
    d.n_trials, d.skipped, d.scenario = len(measurements), skipped, scen
    d.timings["total"] = time.perf_counter() - t_start
    return d


def _check_inputs(scenario: Scenario | str, candidates: Sequence[str] | None,
                  placement_sd: float | None) -> tuple[Scenario, list[str], TrialModel, float]:
    """The scenario, the candidate effects, the task's trial model and the placement scatter; :class:`DiagnosisError`
    for unknown candidates, a task without a diagnosis or a bad placement scatter."""
    from besdrake.task import DEFAULT_TASK, TaskError, effects_for, effects_not_for

    scen = load_scenario(scenario) if not isinstance(scenario, Scenario) else scenario
    try:
        model = model_for(scen)
    except TaskError as err:
        raise DiagnosisError(str(err)) from None
    known = list_effects()
    task = getattr(scen, "task", None) or DEFAULT_TASK
    cands = list(effects_for(task) if candidates is None else candidates)
    unknown = [c for c in cands if c not in known]
    if unknown:
        raise DiagnosisError(f"unknown candidate effect(s) {unknown}; registered effects: {known}")
    foreign = effects_not_for(task, cands)
    if foreign:
        raise DiagnosisError(f"candidate effect(s) {foreign} do not act on {task} rollouts; those that do: {effects_for(task)}")
    if not cands:
        raise DiagnosisError("no candidate effects to fit")
    sc = model.scatter
    if placement_sd is None:
        placement_sd = sc.default_sd if sc is not None else 0.0
    top = sc.max_sd if sc is not None else 0.0
    if not (np.isfinite(placement_sd) and 0.0 <= placement_sd <= top):
        raise DiagnosisError(f"placement_sd must be within 0..{top:g} m ({sc.range_what if sc else 'the task has no placement scatter'}), got {placement_sd!r}")
    return scen, cands, model, placement_sd


def _split_usable(measurements: list, model: TrialModel) -> tuple[list, list[dict]]:
    """The usable trials and the skipped ones (trial and reason); :class:`DiagnosisError` below MIN_TRIALS."""
    used, skipped = [], []
    for m in measurements:
        ok, why = model.usable(m)
        (used if ok else skipped).append(m if ok else {"trial": m.trial, "reason": why})
    if len(used) < MIN_TRIALS:
        raise DiagnosisError(f"only {len(used)} usable {model.plural()} in the log ({len(skipped)} skipped); the diagnosis needs at least {MIN_TRIALS}")
    return used, skipped


def _diagnose_evidence(ev: Evidence, cands: list[str], pairs: bool, folds: int, refine_top: int, iterations: int, rng: np.random.Generator,
                       placement_sd: float, timings: dict[str, float], ident: Identifiability | None = None) -> Diagnosis:
    """Steps 2-4 on the replayed log: fit the candidates, choose and judge the cause, measure the held-out gain."""
    comparison = compare(ev)
    t0 = time.perf_counter()
    specs, spec_notes = fitting.param_specs(cands, ev.model.ordered_params)
    sens = fitting.compute_sensitivity(specs, ev.y0, lambda effs: ev.sim.features(effs))
    timings["sensitivity"] = time.perf_counter() - t0
    prob, fits = fit_linear(ev, sens, cands, pairs)
    notes = list(ev.nm.notes) + spec_notes + _placement_note(ev, placement_sd)
    t0 = time.perf_counter()
    local_shift = refine_leaders(prob, fits, sens, ev.sim, ev.nm, ev.measured_groups, pairs, refine_top, iterations)
    none_fit = next(f for f in fits if not f.effects)
    none_fit.refined, none_fit.y_fit = True, ev.y0
    timings["refine"] = time.perf_counter() - t0
    rank(fits)
    choice_notes: list[str] = []
    best_fit = parsimony(prob, fits, ev.nm, ev.measured_groups, cands, ev.keys, choice_notes)
    best_fit = settle(prob, fits, best_fit, ev.sim, ev.nm, ev.measured_groups, cands, ev.keys, choice_notes, iterations, local_shift)
    notes += choice_notes
    best_shift = local_shift.get(best_fit.effects)
    fitting.jacobian_at(prob, best_fit, lambda effs: ev.sim.features(effs, shift=best_shift))
    causes = rank_causes(prob, fits, best_fit, ev.nm, ev.measured_groups)
    others = [s_ for s_ in sens.specs if s_.effect not in best_fit.effects]
    local = (lambda: fitting.sensitivity_at(others, best_fit.parameters(), best_fit.y_fit, lambda effs: ev.sim.features(effs, shift=best_shift))) \
        if best_fit.y_fit is not None else None
    v = judge(prob, sens, fits, causes, ev, cands, ident, local_sens=local)
    _name_needed_parameters(v, prob, sens, ev, best_shift, iterations, notes)
    _list_rivals_beating_the_named(v, ev, ident, notes)
    name_second_effect_shift(v)
    t0 = time.perf_counter()
    gain, per_trial_after = heldout_gain(ev, sens, v.best_fit, best_shift, folds, iterations, rng)
    timings["heldout"] = time.perf_counter() - t0
    y_best = v.best_fit.y_fit if v.best_fit.y_fit is not None else ev.y0
    per_trial = per_trial_table(ev, y_best, per_trial_after)
    residual = None
    if not v.explained:  # still "not explained"; beside it, where the residual lives and a data-driven model of it
        rep = residual_report(ev, prob, y_best, folds, rng)
        residual = rep.to_dict()
        v.text += "; " + rep.describe()
    notes += ev.signal.notes
    return Diagnosis(
        explained=v.explained, confidence=v.confidence, verdict=v.text, causes=v.causes, best=v.best, indistinguishable=v.indist, noise=ev.nm,
        comparison=comparison, gain=gain, groups_measured=ev.measured_groups, n_trials=len(ev.used), n_used=len(ev.used), skipped=[], per_trial=per_trial,
        scenario=None, timings=timings, n_rollouts=ev.sim.n_rollouts, notes=notes, cannot_tell=v.cannot_tell, excluded=v.excluded,
        structural=[{"members": c.members, "reason": c.statement()} for c in ident.classes] if ident is not None else [], residual=residual, confidence_basis=v.basis,
    )


def _name_needed_parameters(v: Verdict, prob: fitting.Problem, sens: fitting.Sensitivity, ev: Evidence, shift, iterations: int,
                            notes: list[str]) -> None:
    """The named cause less the parameters the log does not need (:func:`~besdrake.diagnosis.parameters.prune_parameters`):
    it replaces the judged fit in ``v`` (what is named, refined and held out), while the verdict and its confidence stay
    those of the cause as selected, against which the rivals and second effects were judged."""
    if not settings.PRUNE_PARAMETERS or not v.explained or not v.best.effects or v.best_fit.y_fit is None:
        return  # a cause that leaves a residual above the noise has no adequate subset either
    full = v.best_fit
    n_params = Counter(s_.effect for s_ in sens.specs)
    pruned, dropped = prune_parameters(prob, full, lambda e: ev.sim.one(e, shift=shift), ev.nm, ev.measured_groups, n_params, iterations)
    if not dropped:
        return
    fitting.jacobian_at(prob, pruned, lambda effs: ev.sim.features(effs, shift=shift))
    notes.append(f"{full.name}: {', '.join(dropped)} left at nominal: without them the fit is still adequate and its predictions "
                 f"stay within {MATERIAL} noise SD of the fit with them (chi2 {full.chi2:.1f} -> {pruned.chi2:.1f})")
    cause = rank_causes(prob, [pruned], pruned, ev.nm, ev.measured_groups)[0]
    v.fits[next(i for i, f in enumerate(v.fits) if f is full)] = pruned
    v.causes[next(i for i, c in enumerate(v.causes) if c is v.best)] = cause
    v.best_fit, v.best = pruned, cause


def _list_rivals_beating_the_named(v: Verdict, ev: Evidence, ident: Identifiability | None, notes: list[str]) -> None:
    """Rivals that fit better than the named cause with only its needed parameters (:func:`~besdrake.diagnosis.verdict.
    rivals_beating`) join "cannot tell"; a separable one makes the answer "low" (honest, not a new choice: the named cause
    stays the one selected)."""
    if not settings.LIST_RIVALS_BEATING_NAMED or not v.explained or not v.best.effects:
        return
    beaten = rivals_beating(v, ev, ident)
    if not beaten:
        return
    v.indist.extend(beaten)
    names = ", ".join(f"{a['b']} ({-a['delta_bic']:.1f} BIC better)" for a in beaten)
    notes.append(f"{v.best_fit.name} with only its needed parameters fits worse than {names}: listed as rivals the log cannot tell from it")
    separable = [a["b"] for a in beaten if not a.get("structural")]
    if separable:
        v.confidence = "low"
        v.text += "; with only its needed parameters it fits worse than " + ", ".join(separable) + ": cannot tell it from them"
    v.basis["rivals_beating_named"] = [a["b"] for a in beaten]


def _placement_note(ev: Evidence, placement_sd: float) -> list[str]:
    if not ev.placement_summary:
        return []
    sc = ev.model.scatter
    return [f"every simulated {ev.model.noun} is the mean over {sc.what} ({placement_sd * 1000:g} mm SD per axis, "
            f"{len(sc.points(placement_sd))} placements); mean correction per group: " + ", ".join(f"{g} {v}" for g, v in ev.placement_summary.items())]


__all__ = ["diagnose", "Diagnosis", "Cause", "Gain", "AllowedEffect", "EXCLUDE_FRACTION", "GroupComparison", "DiagnosisError", "ALPHA", "INDISTINGUISHABLE_DBIC"]
