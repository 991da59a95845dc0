"""Sequential design: after a first log, the plans that tell its leading causes apart.

A first diagnosis ranks the registry's causes on a short log. Where a rival fits nearly as well as the named cause
(one effect absorbing another, a second effect barely shown), more of the same plans add little. Two follow-up
designs, both from a pool of the task's own random designs (other seeds) and both local (at the first log's fits,
centred placement):

* :func:`informative_plans` (the CLI's ``--after``): D-optimal for the parameters of the leading causes *at the named
  cause's fit*, given what the logged plans already show (Ds-optimality restricted to the causes that matter;
  sensitivities by one-sided differences, per realistic range and typical noise, as
  :mod:`~besdrake.diagnosis.optimal_design` does at nominal). A rival's second effect counts by what its parameters
  could show beside the named cause's, even where the first log fitted it near nominal.
* :func:`discriminating_plans`: the plans where the *fitted* leader and rivals predict most differently (Box & Hill
  1967; Atkinson & Fedorov 1975, T-optimality): each plan adds its predicted separation
  ``sum ((y_leader - y_rival) / typical noise)^2`` over the measured observables to each rival's running total, which
  starts at the rival's chi-square gap on the first log; greedy on ``sum_rival log(1 + total / SCALE)`` (the close
  rivals first). Blind to a rival whose extra effect was fitted at nominal.

The most informative chosen plans are run twice (repeats for the noise estimate). What a design gains is stated
against the task's random design of the same size (which is in the pool too). Measured with
``scripts/bench_diagnosis.py --design sequential`` (the default task's CALIBRATION.md, "A sequential experiment").

Knows no task: plans, observables and designs come from the scenario's :class:`~besdrake.diagnosis.trials.TrialModel`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

#: Leading causes the follow-up separates from the named one.
RIVALS = 3
#: Random designs of the task (seeds after the first log's) pooled as candidate plans.
POOL_DESIGNS = 4
#: Chi-square scale of the utility: separations far beyond it count little more.
SCALE = 10.0


@dataclass
class DiscriminatingDesign:
    """A follow-up log (``plans``, shuffled) and the leader and rivals it tells apart (cause names);
    :func:`discriminating_plans` gives per rival the predicted chi-square separation from the leader over the chosen
    plans and over the task's random design (empty from :func:`informative_plans`)."""

    plans: list
    leader: str
    rivals: list[str]
    separation: dict[str, float]
    reference_separation: dict[str, float]
    #: :func:`informative_plans`: per parameter key its information given the others, over the random design's.
    gain: dict[str, float] = field(default_factory=dict)


def cause_effects(cause) -> dict:
    """A ranked cause's fitted effects as a scenario's effects dict (``{effect: {parameter: value}}``)."""
    out: dict = {}
    for p in cause.parameters:
        out.setdefault(p["effect"], {})[p["parameter"]] = float(p["value"])
    return out


def leading_causes(diagnosis, k: int = RIVALS) -> list:
    """The named cause first, then the ``k`` best-ranked causes with another set of effects."""
    leader = diagnosis.best
    rivals = [c for c in sorted(diagnosis.causes, key=lambda c: c.delta_bic) if tuple(c.effects) != tuple(leader.effects)]
    return [leader] + rivals[:k]


def predicted_features(executor, model, plans: Sequence, effects: Sequence[dict], columns: np.ndarray) -> np.ndarray:
    """Features (causes, plans, F) of each plan under each effects dict, divided by each group's typical noise;
    NaN where a rollout failed."""
    nominal = executor.evaluate(list(plans), [{}] * len(plans))
    layouts = [model.full_layout(model.nominal_layout(o)) for o in nominal]
    scale = np.concatenate([np.full(o.size, o.typical) for o in model.observables])[columns]
    outs = executor.evaluate([p for _ in effects for p in plans], [e for e in effects for _ in plans])
    n = len(plans)
    f = np.array([[model.simulated_features(outs[c * n + i], layouts[i])[columns] for i in range(n)] for c in range(len(effects))], dtype=float)
    return f / scale


def separations(features: np.ndarray) -> np.ndarray:
    """Per plan and rival (N, R) the squared scaled distance of the rival's prediction from the leader's (row 0);
    0 where either is missing."""
    d = features[1:] - features[:1]
    return np.nansum(d**2, axis=2).T


def greedy_discriminating(sep: np.ndarray, start: np.ndarray, k: int, scale: float = SCALE) -> list[int]:
    """``k`` distinct plan indices, each the one that raises ``sum_r log(1 + (start_r + sum sep[:, r]) / scale)`` most."""
    total, left, chosen = np.asarray(start, dtype=float).copy(), list(range(len(sep))), []
    for _ in range(min(k, len(left))):
        gains = [np.sum(np.log1p((total + sep[i]) / scale)) for i in left]
        best = left.pop(int(np.argmax(gains)))
        chosen.append(best)
        total += sep[best]
    return chosen


def _pool(model, n: int, repeats: int, first_seed: int, limits, options: dict) -> tuple[list, list[int]]:
    """Distinct candidate plans and, with multiplicity, the pool indices of the reference: the task's own random
    design of ``n`` plans (seed ``first_seed + 1``); the other candidates come from :data:`POOL_DESIGNS` designs of
    ``2 n`` plans (the seeds after it)."""
    from besdrake.transfer.measurement import plan_hash

    plans, index, reference = [], {}, []
    sizes = [n] + [2 * n] * POOL_DESIGNS
    for j, size in enumerate(sizes):
        for p in model.design_experiments(size, repeats, seed=first_seed + 1 + j, limits=limits, **options):
            h = plan_hash(p)
            if h not in index:
                index[h] = len(plans)
                plans.append(p)
            if j == 0:
                reference.append(index[h])
    return plans, reference


def _request(diagnosis, n: int, repeats: int, rivals: int, who: str) -> tuple:
    """The scenario, the task's trial model, the leading causes and the measured feature columns of a follow-up
    request; :class:`ValueError` for a bad size."""
    from besdrake.diagnosis.trials import model_for

    if not (1 <= n and 0 <= repeats <= n // 2):
        raise ValueError(f"{who}: need n >= 1 and 0 <= repeats <= n/2, got n={n}, repeats={repeats}")
    scen = diagnosis.scenario
    model = model_for(scen)
    sl = model.slices()
    columns = np.concatenate([np.arange(sl[g].start, sl[g].stop) for g in diagnosis.groups_measured])
    return scen, model, leading_causes(diagnosis, rivals), columns


def _shuffled(pool: list, indices: list[int], seed: int) -> list:
    log = [pool[i] for i in indices]
    return [log[int(i)] for i in np.random.default_rng(seed).permutation(len(log))]


def discriminating_plans(diagnosis, n: int, repeats: int, executor, seed: int = 0, rivals: int = RIVALS,
                         design_options: dict | None = None) -> DiscriminatingDesign:
    """A follow-up log of ``n`` plans (``repeats`` of them run twice) that separates ``diagnosis``'s named cause
    from its ``rivals`` leading rivals (see the module docstring); ``seed`` draws the pool's designs (seeds
    ``seed + 1 ...``) and the log's order; ``design_options``: the task's design keywords. :class:`ValueError` for
    a bad request."""
    scen, model, causes, columns = _request(diagnosis, n, repeats, rivals, "discriminating_plans")
    if len(causes) < 2:
        raise ValueError("discriminating_plans: the diagnosis ranked no rival to the named cause")
    pool, reference = _pool(model, n, repeats, seed, scen.robot.limits, design_options or {})
    feats = predicted_features(executor, model, pool, [cause_effects(c) for c in causes], columns)
    ok = np.all(np.isfinite(feats[0]), axis=1)
    sep = np.where(ok[:, None], separations(feats), 0.0)
    start = np.array([max(0.0, c.chi2 - causes[0].chi2) for c in causes[1:]])
    k = n - repeats
    chosen = greedy_discriminating(sep, start, k, SCALE) if ok.sum() >= k else []
    if len(chosen) < k or not all(ok[i] for i in chosen):
        raise ValueError(f"discriminating_plans: only {int(ok.sum())} of {len(pool)} candidate plans simulate under the leader; {k} needed")
    again = sorted(chosen, key=lambda i: -np.sum(np.log1p(sep[i] / SCALE)))[:repeats]
    names = [_name(c) for c in causes]
    total = sep[chosen + again].sum(axis=0)
    return DiscriminatingDesign(_shuffled(pool, chosen + again, seed), names[0], names[1:],
                                dict(zip(names[1:], map(float, total))), dict(zip(names[1:], map(float, sep[reference].sum(axis=0)))))


def relevant_specs(causes: Sequence, model) -> list:
    """The parameter specs of every effect of the leading causes, in the order they appear."""
    from besdrake.diagnosis.fitting import param_specs

    effects = list(dict.fromkeys(e for c in causes for e in c.effects))
    return param_specs(effects, model.ordered_params)[0]


def sensitivities_at(executor, model, plans: Sequence, specs: Sequence, base: dict, columns: np.ndarray) -> np.ndarray:
    """Per plan (N, P, F) the features' change per realistic range of each parameter of ``specs`` at the effects
    ``base`` (the others at nominal), in units of the typical noise: one-sided differences of the spec's step."""
    from besdrake.diagnosis.fitting import effects_from

    theta = np.array([base.get(s_.effect, {}).get(s_.name, s_.nominal) for s_ in specs], dtype=float)
    steps, variants = [], [effects_from(specs, theta)]
    for i, s_ in enumerate(specs):
        h = s_.step if s_.low <= theta[i] + s_.step <= s_.high else -s_.step
        t = theta.copy()
        t[i] += h
        steps.append(h / (s_.high - s_.low))
        variants.append(effects_from(specs, t))
    f = predicted_features(executor, model, plans, variants, columns)
    J = (f[1:] - f[:1]) / np.asarray(steps)[:, None, None]
    return np.nan_to_num(J).transpose(1, 0, 2)


def informative_plans(diagnosis, logged_plans: Sequence, n: int, repeats: int, executor, seed: int = 0, rivals: int = RIVALS,
                      design_options: dict | None = None) -> DiscriminatingDesign:
    """A follow-up log of ``n`` plans (``repeats`` run twice) that is D-optimal for the parameters of the leading
    causes *at the named cause's fit* (Ds-optimality on the causes that matter, given what ``logged_plans`` already
    show): where :func:`discriminating_plans` needs a rival's second effect fitted away from nominal to see it, the
    information counts what each of its parameters could still show beside the named cause's. ``gain``: each
    parameter's information given the others against the task's random design of the same size."""
    from besdrake.diagnosis.optimal_design import PRIOR_PRECISION, blocks_of, conditional_information, greedy_d_optimal, information
    from besdrake.transfer.measurement import plan_hash

    scen, model, causes, columns = _request(diagnosis, n, repeats, rivals, "informative_plans")
    specs = relevant_specs(causes, model)
    if not specs:
        raise ValueError("informative_plans: the leading causes have no parameters to inform")
    pool, reference = _pool(model, n, repeats, seed, scen.robot.limits, design_options or {})
    hashes = [plan_hash(p) for p in logged_plans]
    logged = {h: p for h, p in zip(hashes, logged_plans)}  # distinct, in first-seen order
    J = sensitivities_at(executor, model, pool + list(logged.values()), specs, cause_effects(causes[0]), columns)
    blocks = blocks_of(J)
    at = {h: len(pool) + j for j, h in enumerate(logged)}
    base = information(blocks, {at[h]: hashes.count(h) for h in logged}, PRIOR_PRECISION * np.eye(len(specs)))
    k = n - repeats
    chosen = greedy_d_optimal(blocks[: len(pool)], base, k)
    if len(chosen) < k:
        raise ValueError(f"informative_plans: only {len(pool)} candidate plans; {k} needed")
    again = chosen[:repeats]
    M = information(blocks, {i: 1 + again.count(i) for i in chosen}, base)
    R = information(blocks, {i: reference.count(i) for i in set(reference)}, base)
    keys = [s_.key for s_ in specs]
    gain = {key: float(g / r) if r > 0 else float("nan") for key, g, r in zip(keys, conditional_information(M), conditional_information(R))}
    names = [_name(c) for c in causes]
    return DiscriminatingDesign(_shuffled(pool, chosen + again, seed), names[0], names[1:], {}, {}, gain)


def _name(cause) -> str:
    return " + ".join(cause.effects) if cause.effects else "none"


__all__ = ["discriminating_plans", "informative_plans", "relevant_specs", "sensitivities_at", "DiscriminatingDesign", "leading_causes", "cause_effects", "greedy_discriminating", "separations",
           "predicted_features", "RIVALS", "POOL_DESIGNS", "SCALE"]
