"""Step 1 of a diagnosis: the logged trials replayed in the nominal simulation, their features, the noise model, the
group-by-group comparison, and the candidates fitted on the linear model."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from besdrake.diagnosis import fitting, noise, settings
from besdrake.diagnosis.results import GroupComparison
from besdrake.diagnosis.settings import SYSTEMATIC_Z
from besdrake.diagnosis.simulate import _placement_correction, _Sim
from besdrake.diagnosis.trials import SignalNoise, TrialModel, model_for
from besdrake.sim.scenario import Scenario


@dataclass
class Evidence:
    """The usable trials against the nominal simulation: what every later step reads.

    ``y_meas``/``y0``: measured and nominal (expected over the placement scatter) features (N, F); ``nm``: the noise
    model; ``measured_groups``: the feature groups the log has (at least two trials); ``sim``: the rollouts (its
    ``model``: the task's trials); ``signal``: the noise the log's own signals show."""

    used: list
    plans: list
    keys: list[str]
    sim: _Sim
    y_meas: np.ndarray
    y0: np.ndarray
    nm: noise.NoiseModel
    measured_groups: list[str]
    signal: SignalNoise
    placement_summary: dict[str, Any] = field(default_factory=dict)

    @property
    def layouts(self) -> list:
        return self.sim.layouts

    @property
    def model(self) -> TrialModel:
        return self.sim.model


def replay(used: list, keys: list[str], ex, cache: dict | None, scen: Scenario, placement_sd: float, model: TrialModel | None = None) -> Evidence:
    """Replay every used plan in the nominal simulation (and over the placement scatter), read the features of the
    lab and the simulation at the same windows, and estimate the noise. ``model``: the task's trials (default: the
    scenario's task's)."""
    model = model or model_for(scen)
    plans = [m.plan for m in used]
    sim = _Sim(ex, plans, keys, [], [], cache, model=model)
    nominal = sim.outcomes([{}], range(len(plans)))[0]
    sim.layouts = [model.make_layout(m, o) for m, o in zip(used, nominal)]
    sim.full_layouts = [model.full_layout(lay) for lay in sim.layouts]
    layouts = sim.layouts
    placement_summary = _placement_correction(sim, scen, placement_sd)
    meas, rms = [], []
    for m, lay in zip(used, layouts):
        f, r = model.measured_features(m, lay)
        meas.append(f)
        rms.append(r)
    y_meas = np.array(meas)
    y0 = np.array([model.simulated_features(o, lay) for o, lay in zip(nominal, layouts)]) + sim.shift
    sim.full_cache[sim.key({})] = np.array([model.simulated_features(o, lay) for o, lay in zip(nominal, sim.full_layouts)]) + sim.full_shift
    measured_groups = noise.measured_groups(y_meas, model)
    signal = model.signal_noise(used, layouts, rms)
    nm = noise.estimate_noise(y_meas, keys, signal, place_var=sim.place_var, model=model, place_cov=sim.place_cov)
    return Evidence(used, plans, keys, sim, y_meas, y0, nm, measured_groups, signal, placement_summary)


def compare(ev: Evidence) -> list[GroupComparison]:
    """Per measured group: the mean sim-vs-lab residual, its standard error, and whether it is systematic."""
    comparison = []
    resid0 = ev.y_meas - ev.y0
    for g, s in ev.model.slices().items():
        if g not in ev.measured_groups:
            continue
        block = resid0[:, s]
        b = block[np.all(np.isfinite(block), axis=1)]
        sd = ev.nm.sd[g]
        se = np.full(b.shape[1], sd / np.sqrt(len(b)))
        mean = b.mean(axis=0)
        z = np.abs(mean) / se
        chi2 = float(np.sum((b / sd) ** 2))
        comparison.append(GroupComparison(g, ev.model.units()[g], int(len(b)), mean.tolist(), se.tolist(), float(np.sqrt(np.mean(b**2))), sd,
                                          bool(np.any(z > SYSTEMATIC_Z)), chi2, int(b.size)))
    return comparison


def fit_linear(ev: Evidence, sens: fitting.Sensitivity, cands: list[str], pairs: bool) -> tuple[fitting.Problem, list[fitting.CandidateFit]]:
    """Every candidate (and pair) fitted on the linear model at nominal, ranked by BIC. Without repeated plans the
    other groups' trial-to-trial scatter (all but the outcome's) is unknown: it is taken from the best linear candidate's residual
    (profile likelihood; ``ev.nm`` is scaled in place) so that they do not dominate the ranking."""
    prob, fits = _fit_all(ev, sens, cands, pairs)
    nm, sl, outcome = ev.nm, ev.model.slices(), ev.model.outcome
    if nm.n_repeat_groups == 0 or any(nm.dof.get(g, 0) == 0 for g in ev.measured_groups if g != outcome):
        best_lin = fits[0]
        y_lin = (ev.y0 + np.tensordot(best_lin.theta - np.array([s.nominal for s in best_lin.specs]), sens.dy[[sens.specs.index(s) for s in best_lin.specs]], axes=1)
                 if best_lin.specs else ev.y0)
        c2 = fitting.chi2_by_group(prob, y_lin, sl)
        changed = False
        for g in ev.measured_groups:
            if g == outcome or nm.dof.get(g, 0) > 0:
                continue
            n_g = int(prob.mask[:, sl[g]].sum())
            if n_g and c2.get(g, 0) / n_g > 1.0:
                nm.scale_group(g, float(np.sqrt(c2[g] / n_g)))
                nm.source[g] += "; scaled to the best candidate's residual scatter (no repeated plans)"
                changed = True
        if changed:
            prob, fits = _fit_all(ev, sens, cands, pairs)
    return prob, fits


def _fit_all(ev: Evidence, sens: fitting.Sensitivity, cands: list[str], pairs: bool) -> tuple[fitting.Problem, list[fitting.CandidateFit]]:
    prob = fitting.Problem(ev.y_meas, ev.y0, ev.nm.matrix(len(ev.y_meas)), cov=ev.nm.covariances(len(ev.y_meas)))
    fits = [fitting.linear_fit(prob, sens, c, select=settings.SELECT_PARAMETERS) for c in fitting.candidate_sets(cands, pairs)]
    fits.sort(key=lambda f: f.bic)
    return prob, fits
