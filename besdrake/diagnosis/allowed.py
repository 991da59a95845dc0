"""What a log without a detectable discrepancy still allows of each candidate effect (``cannot_tell``/``excluded``)."""

from __future__ import annotations

from typing import NamedTuple, Sequence

import numpy as np
from scipy import stats

from besdrake.diagnosis import fitting
from besdrake.diagnosis.results import AllowedEffect
from besdrake.diagnosis.settings import ALPHA, EXCLUDE_FRACTION, HIDE_WIDENING, MAX_TRIALS_ADVICE, UNCONSTRAINED_COVER, VERIFY_ROUNDS
from besdrake.diagnosis.simulate import _Sim


class _Line(NamedTuple):
    """One parameter's linearised allowed interval: estimate, ends (within the realistic bounds), half-width, and
    the information (squared weighted sensitivity) behind it."""

    spec: fitting.ParamSpec
    est: float
    lo: float
    hi: float
    half: float
    info: float


def _verify_interval_ends(prob: fitting.Problem, sim: _Sim, lin: dict[str, _Line], c0: float, q: float,
                          rounds: int = VERIFY_ROUNDS) -> dict[str, tuple[float, float]]:
    """The allowed interval of each parameter (key -> :class:`_Line`) with its ends checked by rollouts. An end
    inside the realistic bounds stands when the real chi-square there (with the weak prior) exceeds the lowest one
    seen on that parameter's line (nominal ``c0``, the estimate, the points tried) by ``q``. Otherwise the end moves outwards (quadratic profile through the lowest point, at most twice as far per
    round, the bound itself as the last try) until a point passes, and then is bisected back towards the last point
    that did not (to within a tenth of its distance from the lowest point or 1% of the range): the end reported is the
    innermost point that passed, or the bound when none did within ``rounds``.
    So the answer may say less than the data allow, never that a deviation "would have been seen" which the
    simulation does not show. One batch of rollouts per round."""
    def prior(s_: fitting.ParamSpec, v: float) -> float:  # the fit's weak prior, as a chi-square term
        return float(fitting._prior_rows([s_], np.array([v]))[1][0] ** 2)

    best = {k: (c0, ln.spec.nominal) for k, ln in lin.items()}  # lowest chi2 seen on the line and where
    # Per end still open: [key, side, point to try, inner (seen, not ruled out), outer (ruled out)].
    ends = {k: [ln.lo, ln.hi] for k, ln in lin.items()}
    todo = [[k, side, v, None, None] for k, ln in lin.items() if ln.lo <= ln.hi
            for side, v in ((0, ln.lo), (1, ln.hi)) if ln.spec.low < v < ln.spec.high]
    extra = [(k, lin[k].est) for k in {t[0] for t in todo}
             if lin[k].spec.low < lin[k].est < lin[k].spec.high and abs(lin[k].est - lin[k].spec.nominal) > 0.25 * lin[k].half]
    for _ in range(rounds):
        if not todo:
            break
        pts = extra + [(t[0], t[2]) for t in todo]
        Y = sim.features([fitting.effects_from([lin[k].spec], np.array([v])) for k, v in pts])
        chi = {}
        for (k, v), y in zip(pts, Y):
            r = prob.weighted(y)
            chi[(k, v)] = c = float(r @ r) + prior(lin[k].spec, v)
            if c < best[k][0]:
                best[k] = (c, v)
        extra, nxt = [], []
        for t in todo:
            k, side, v, inner, outer = t
            s_ = lin[k].spec
            bound = s_.low if side == 0 else s_.high
            c_min, v_min = best[k]
            gap = chi[(k, v)] - c_min
            if gap >= q:
                outer = v
            else:
                inner = v
            if outer is None and inner == bound:
                ends[k][side] = bound  # nothing ruled out up to the bound
                continue
            if outer is not None and (inner is None or abs(outer - inner) <= max(0.1 * abs(outer - v_min), 0.01 * (s_.high - s_.low))):
                ends[k][side] = outer  # the linear end itself holds, or the bracket is narrow enough
                continue
            if outer is None:  # step outwards
                if v == v_min:  # the lowest point seen: the line falls further out, one half-width on
                    d = lin[k].half
                else:
                    d = abs(v - v_min) * min(2.0, 1.1 * np.sqrt(q / max(gap, 1e-12)))
                nv = v_min - d if side == 0 else v_min + d
                nv = max(nv, bound) if side == 0 else min(nv, bound)
            else:  # bisect between the last point not ruled out and the innermost one ruled out
                nv = 0.5 * (inner + outer)
            nxt.append([k, side, float(nv), inner, outer])
        todo = nxt
    for k, side, _v, _i, outer in todo:  # rounds used up: the innermost point ruled out, else the bound
        ends[k][side] = outer if outer is not None else (lin[k].spec.low if side == 0 else lin[k].spec.high)
    return {k: (float(lo), float(hi)) for k, (lo, hi) in ends.items()}


def _allowed_effects(prob: fitting.Problem, sens: fitting.Sensitivity, effects: Sequence[str], sim: _Sim, measured: list[str],
                     n_trials: int) -> list[AllowedEffect]:
    """For a log in which no candidate improves on the nominal simulation: per candidate effect, the parameter
    intervals the data still allow (each parameter on its own with the effect's others at nominal, linearised
    likelihood-ratio interval at level ALPHA with the fit's weak prior, its ends checked by rollouts, within the
    realistic bounds),
    whether every deviation of EXCLUDE_FRACTION of the range is ruled out, and what would show the effect."""
    q = float(stats.chi2.ppf(1.0 - ALPHA, 1))
    r0 = prob.weighted(sens.y0)
    lin = _linear_intervals(prob, sens, effects, r0, q)
    # ... then every end that the data (not a realistic bound) set is checked with rollouts and widened where the
    # linear model overstated how far the trials respond (e.g. the gains: benchmark seed 0, outcome-only trials 21
    # and 30 stated "kp_scale 0.73..1.19, larger deviations would have been seen" of a lab with kp_scale 0.68).
    checked = _verify_interval_ends(prob, sim, lin, float(r0 @ r0), q)
    hiding = _hiding_pairs(prob, sens, r0, q)
    out = []
    for e in effects:
        specs = [ln.spec for ln in lin.values() if ln.spec.effect == e]
        if specs:
            a = _allowed_effect(e, specs, lin, checked, sim, measured, n_trials, q)
            a.beside = {s_.name: {o: (min(lo, checked[s_.key][0]), max(hi, checked[s_.key][1])) for o, (lo, hi) in hiding[s_.key].items()}
                        for s_ in specs if hiding.get(s_.key)}
            out.append(a)
    return out


#: Points on which :func:`_hiding_pairs` profiles the linearised chi-square of each parameter (alone and per partner),
#: over a window 1.5 times the widest of the two unbounded intervals around their estimates, within the bounds.
HIDE_GRID = 401


def _hiding_pairs(prob: fitting.Problem, sens: fitting.Sensitivity, r0: np.ndarray, q: float) -> dict[str, dict[str, tuple[float, float]]]:
    """Per parameter key: ``{other key: (lo, hi)}``, the interval the log allows the parameter (likelihood ratio at
    level ``q``, linearised chi-square with the fit's weak prior, within the realistic bounds) where the other one moves
    to compensate (profiled within its own bounds), kept where it is at least :data:`HIDE_WIDENING` times as wide as the
    interval the same model allows the parameter alone.

    Why: the intervals the answer states are each parameter's alone, so "larger deviations would have been seen" is
    false for two deviations that cancel (benchmark seed 5, touchdown-only trials 22, 28 and 31: a base pitch of 0.034
    rad beside a joint-3 offset of -0.076 rad left the touchdowns as they were, while the answer allowed the pitch only up
    to 0.010 rad)."""
    specs = list(sens.specs)
    if not specs:
        return {}
    A = prob.weighted_jac(sens.dy)  # whitened sensitivity columns, one per parameter
    G, g = A.T @ A, A.T @ r0
    curv = G.diagonal() + np.diag(fitting._prior_rows(specs, np.array([s_.nominal for s_ in specs]))[0]) ** 2
    lo = np.array([s_.low - s_.nominal for s_ in specs])
    hi = np.array([s_.high - s_.nominal for s_ in specs])
    out: dict[str, dict[str, tuple[float, float]]] = {}
    for i, s_ in enumerate(specs):
        if curv[i] <= 0:
            continue
        alone = _span(_profile_grid(i, None, G, g, curv, lo, hi, q), G, g, curv, lo, hi, i, None, q)
        if alone is None:
            continue
        for k in range(len(specs)):
            if k == i:
                continue
            span = _span(_profile_grid(i, k, G, g, curv, lo, hi, q), G, g, curv, lo, hi, i, k, q)
            if span is not None and span[1] - span[0] >= HIDE_WIDENING * (alone[1] - alone[0]) + 1e-12:
                out.setdefault(s_.key, {})[specs[k].key] = (float(s_.nominal + span[0]), float(s_.nominal + span[1]))
    return out


def _profile_grid(i: int, k: int | None, G: np.ndarray, g: np.ndarray, curv: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                  q: float) -> np.ndarray:
    """Deviations of parameter ``i`` to profile: :data:`HIDE_GRID` points over 1.5 times the unbounded interval alone and
    (with partner ``k``) the unbounded pair interval, around their estimates, within ``i``'s bounds."""
    centre, half = g[i] / curv[i], np.sqrt(q / curv[i])
    a, b = centre - 1.5 * half, centre + 1.5 * half
    if k is not None:
        det = curv[i] * curv[k] - G[i, k] ** 2
        if det > 1e-12 * curv[i] * curv[k]:
            c_p, h_p = (curv[k] * g[i] - G[i, k] * g[k]) / det, np.sqrt(q * curv[k] / det)
            a, b = min(a, c_p - 1.5 * h_p), max(b, c_p + 1.5 * h_p)
        else:  # the two move every feature alike: anything within the bounds
            a, b = lo[i], hi[i]
    return np.linspace(np.clip(a, lo[i], hi[i]), np.clip(b, lo[i], hi[i]), HIDE_GRID)


def _span(d: np.ndarray, G: np.ndarray, g: np.ndarray, curv: np.ndarray, lo: np.ndarray, hi: np.ndarray, i: int, k: int | None,
          q: float) -> tuple[float, float] | None:
    """The smallest and largest deviation of ``d`` (of parameter ``i``) whose linearised chi-square, with partner ``k``
    compensating within its bounds (None: alone), is within ``q`` of the lowest on ``d``."""
    chi = -2.0 * d * g[i] + d * d * curv[i]
    if k is not None:
        db = np.clip((g[k] - G[k, i] * d) / curv[k], lo[k], hi[k]) if curv[k] > 0 else np.zeros_like(d)
        chi = chi - 2.0 * db * g[k] + 2.0 * d * db * G[k, i] + db * db * curv[k]
    if not np.isfinite(chi).any() or d.size == 0:
        return None
    inside = d[chi <= np.nanmin(chi) + q]
    return (float(inside.min()), float(inside.max())) if inside.size else None


def _linear_intervals(prob: fitting.Problem, sens: fitting.Sensitivity, effects: Sequence[str], r0: np.ndarray, q: float) -> dict[str, _Line]:
    """Linearised intervals first (each parameter on its own, the effect's others at nominal: the same sparse view as
    the fit; a realistic deviation moves one or two of an effect's parameters, and the joint profile of e.g. six
    encoder offsets would allow almost anything through their trade-offs and tell nothing) ..."""
    lin: dict[str, _Line] = {}
    for e in effects:
        cols = fitting.effect_columns(prob, sens, e)
        if cols is None:
            continue
        specs, A, P = cols
        for j, s_ in enumerate(specs):
            a = A[:, j]
            info = float(a @ a)
            var = 1.0 / (info + P[j, j] ** 2)
            est = s_.nominal + var * float(a @ r0)
            half = np.sqrt(q * var)
            lin[s_.key] = _Line(s_, est, max(s_.low, est - half), min(s_.high, est + half), half, info)
    return lin


def allowed_range(s_: fitting.ParamSpec, est: float, lo: float, hi: float) -> tuple[float, float, float]:
    """An allowed interval ``[lo, hi]`` already clipped to the realistic bounds (where the estimate lies beyond a bound,
    only the bound itself), and its largest deviation from nominal as a fraction of the range."""
    if lo > hi:
        lo = hi = s_.low if est < s_.low else s_.high
    return lo, hi, max(abs(lo - s_.nominal), abs(hi - s_.nominal)) / (s_.high - s_.low)


def _allowed_effect(e: str, specs: list[fitting.ParamSpec], lin: dict[str, _Line], checked: dict[str, tuple[float, float]], sim: _Sim,
                    measured: list[str], n_trials: int, q: float) -> AllowedEffect:
    """One effect's allowed values (from the checked intervals), whether it is excluded, and what would show it."""
    allowed, nominal, units, fracs, needed = {}, {}, {}, [], []
    for s_ in specs:
        est, info = lin[s_.key].est, lin[s_.key].info
        lo, hi, frac = allowed_range(s_, est, *checked[s_.key])
        rng_ = s_.high - s_.low
        fracs.append(frac)
        allowed[s_.name], nominal[s_.name], units[s_.name] = (float(lo), float(hi)), float(s_.nominal), s_.unit
        if fracs[-1] >= EXCLUDE_FRACTION:  # trials to exclude this parameter: the half-width shrinks as 1/sqrt(trials)
            needed.append(n_trials * q / info / (EXCLUDE_FRACTION * rng_) ** 2 if info > 0 else np.inf)
    max_frac = float(max(fracs))
    excluded = max_frac < EXCLUDE_FRACTION
    n_need = float(max(needed)) if needed else np.inf
    trials_needed = int(np.ceil(n_need)) if np.isfinite(n_need) and n_need <= MAX_TRIALS_ADVICE else None
    rec = "" if excluded else _recommendation(e, specs, sim, measured, trials_needed)
    unconstrained = all(hi_ - lo_ >= UNCONSTRAINED_COVER * (s_.high - s_.low) for s_, (lo_, hi_) in zip(specs, allowed.values()))
    return AllowedEffect(e, allowed, nominal, units, max_frac, excluded, trials_needed, rec, unconstrained)


def _recommendation(e: str, specs: list[fitting.ParamSpec], sim: _Sim, measured: list[str], trials_needed: int | None) -> str:
    """Which signal would show a deviation of EXCLUDE_FRACTION of the range (finite-difference rollouts of the
    sensitivity, evaluated for every signal), else how many trials would, else that none would."""
    model = sim.model
    typical, noun = model.typical(), model.noun
    y_nom_full = sim.full_cache.get(sim.key({}))
    shows = []
    for s_ in specs:
        y_step = sim.full_cache.get(sim.key(fitting.effects_from([s_], [s_.nominal + s_.step])))
        if y_step is None or y_nom_full is None:
            continue
        d = (y_step - y_nom_full) * (EXCLUDE_FRACTION * (s_.high - s_.low) / abs(s_.step))
        for g, sl_ in model.slices().items():
            rms = np.sqrt(np.nanmean(d[:, sl_] ** 2, axis=1))
            rms = rms[np.isfinite(rms)]
            if rms.size:
                shows.append((float(np.median(rms) / typical[g]), g, s_.key))
    shows.sort(reverse=True)
    unmeasured = [x for x in shows if x[1] not in measured and x[0] > 1.0]
    if unmeasured:
        sc, g, key = unmeasured[0]
        return f"{model.group(g).record}: {key} at {EXCLUDE_FRACTION:.0%} of its range would show there as ~{sc:.1f} x typical noise per {noun}"
    if trials_needed is not None:
        return (f"about {trials_needed} {noun}s like the logged ones (with repeats) would exclude {e} beyond {EXCLUDE_FRACTION:.0%} of its range; "
                f"{model.wider_plans_hint()}")
    return (f"no practical number of {noun}s like these would show it in the logged signals (they hardly respond to it); "
            f"record other signals or {model.other_plans_hint()}")
