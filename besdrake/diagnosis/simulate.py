"""Simulated features of the logged plans: batched, memoised rollouts (:class:`_Sim`) and the expected trial over the
lab's placement scatter (:func:`_placement_correction`, the task's :class:`~besdrake.diagnosis.trials.PlacementScatter`)."""

from __future__ import annotations

import json
import warnings
from typing import Any, Sequence

import numpy as np

from besdrake.diagnosis import settings
from besdrake.diagnosis.trials import TrialModel, default_model
from besdrake.sim.scenario import Scenario


class _Sim:
    """Batches rollouts through an executor and turns Outcomes into features.

    Repeated plans are simulated once per parameter set, and Outcomes are memoised by (plan hash, effects)
    in ``cache`` (a dict the caller may share between diagnoses of the same trials, e.g. a full and an
    outcome-only view of one log). ``n_rollouts`` counts the rollouts actually run. ``model``: the task's trials
    (default: the default task's).
    """

    def __init__(self, executor, plans, keys, layouts, full_layouts, cache: dict | None = None, model: TrialModel | None = None):
        self.ex, self.plans, self.keys, self.layouts, self.full_layouts = executor, plans, keys, layouts, full_layouts
        self.model = model or default_model()
        self.n_rollouts = 0
        self.cache: dict = {} if cache is None else cache
        self.full_cache: dict[str, np.ndarray] = {}
        # Expected-placement corrections (N, F) added to every simulated feature vector (zeros: none).
        self.shift = np.zeros((len(plans), self.model.n_features))
        self.full_shift = np.zeros((len(plans), self.model.n_features))
        # Predicted placement variance per trial and feature (None: the lab's placement does not scatter), and the
        # covariance between a trial's features over the same placements (N, F, F; NaN-free, its diagonal place_var).
        self.place_var: np.ndarray | None = None
        self.place_cov: np.ndarray | None = None
        # Placement draws (K, 2) around the scenario's placement (``placement_habit``), clipped to the bounds.
        self.placement_draws: np.ndarray | None = None
        self.expand_all = False  # every candidate (not only those that set the placement) averaged over the draws
        self.placement_habit: dict[str, float] = {}

    @staticmethod
    def key(effects: dict) -> str:
        return json.dumps(effects, sort_keys=True)

    def outcomes(self, effects_list: list[dict], rows: Sequence[int]) -> list[list]:
        todo: dict[tuple[str, str], tuple] = {}
        for e in effects_list:
            ek = self.key(e)
            for i in rows:
                ck = (self.keys[i], ek)
                if ck not in self.cache and ck not in todo:
                    todo[ck] = (self.plans[i], e)
        if todo:
            items = list(todo.items())
            outs = self.ex.evaluate([p for _, (p, _e) in items], [e for _, (_p, e) in items])
            self.n_rollouts += len(outs)
            for (ck, _), o in zip(items, outs):
                self.cache[ck] = o
        return [[self.cache[(self.keys[i], self.key(e))] for i in rows] for e in effects_list]

    def _expand(self, effects: dict) -> list[dict]:
        """The effects dicts whose mean is this candidate's expected trial: the placement draws around the
        candidate's own placement when it sets the placement effect (and draws are set), else the candidate itself."""
        pe = self.model.scatter.effect if self.model.scatter is not None else None
        if self.placement_draws is None or (pe not in effects and not (self.expand_all and effects)):
            return [effects]
        own = {**self.placement_habit, **effects.get(pe, {})}
        out = []
        for d in self.placement_draws:
            e = {k: dict(v) for k, v in effects.items()}
            e[pe] = self.model.scatter.placed(own, d)
            out.append(e)
        return out

    def features(self, effects_list: list[dict], rows: Sequence[int] | None = None, shift: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """Expected features (len(effects_list), N, F) with NaN rows outside ``rows``: a candidate that sets the
        placement is averaged over the placement draws around it, any other gets the placement correction added: the
        nominal one (``self.shift``/``self.full_shift``) or ``shift`` = (shift, full_shift), e.g. a candidate's own
        (:meth:`local_shift`)."""
        rows = list(range(len(self.plans))) if rows is None else list(rows)
        sh, full_sh = (self.shift, self.full_shift) if shift is None else shift
        expanded = [self._expand(e) for e in effects_list]
        flat = [x for ex_ in expanded for x in ex_]
        outs = self.outcomes(flat, rows)
        n_f, feat = self.model.n_features, self.model.simulated_features
        Y = np.full((len(effects_list), len(self.plans), n_f), np.nan)
        j = 0
        for a, e in enumerate(effects_list):
            n_e = len(expanded[a])
            ys = np.full((n_e, len(self.plans), n_f), np.nan)
            fulls = np.full((n_e, len(self.plans), n_f), np.nan)
            for b in range(n_e):
                for i, o in zip(rows, outs[j + b]):
                    ys[b, i] = feat(o, self.layouts[i])
                    fulls[b, i] = feat(o, self.full_layouts[i])
            j += n_e
            if n_e == 1:
                Y[a], full = ys[0] + sh, fulls[0] + full_sh
            else:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)  # all draws failed: NaN, as a failed rollout
                    Y[a], full = np.nanmean(ys, axis=0), np.nanmean(fulls, axis=0)
            k = self.key(e)
            prev = self.full_cache.get(k)
            if prev is not None:
                full = np.where(np.isfinite(full), full, prev)
            self.full_cache[k] = full
        return Y

    def one(self, effects: dict, rows: Sequence[int] | None = None, shift: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        return self.features([effects], rows, shift)[0]

    def local_shift(self, effects: dict) -> tuple[np.ndarray, np.ndarray] | None:
        """The placement correction at a candidate's own parameters (measured and full layouts): the mean over the
        placement draws around the scenario's placement minus the candidate with the object there (one rollout per draw
        and trial). None when no draws are set or the candidate sets the placement itself (it is averaged exactly)."""
        if self.placement_draws is None or self.model.scatter.effect in effects or not effects:
            return None
        draws = []
        for d in self.placement_draws:
            e = {k: dict(v) for k, v in effects.items()}
            e[self.model.scatter.effect] = self.model.scatter.placed(self.placement_habit, d)
            draws.append(e)
        rows = range(len(self.plans))
        outs = self.outcomes([effects] + draws, rows)
        out = []
        for lays in (self.layouts, self.full_layouts):
            f = np.array([[self.model.simulated_features(o, lays[i]) for i, o in zip(rows, per)] for per in outs])
            with np.errstate(invalid="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                sh = np.nanmean(f[1:], axis=0) - f[0]
            out.append(np.where(np.isfinite(sh), sh, 0.0))
        return out[0], out[1]


def _placement_cov(dev: np.ndarray, ww: np.ndarray, place_var: np.ndarray) -> np.ndarray:
    """Per trial, the covariance of its features over the quadrature's placements (N, F, F): the weighted sum of the
    deviations' outer products (``dev`` (K, N, F), weights ``ww`` (K, N, F), a placement whose rollout failed carrying
    no weight for that feature), scaled so that its diagonal is ``place_var``; zero where that is unknown."""
    w = np.sqrt(np.clip(np.nan_to_num(ww), 0.0, None)) * dev
    cov = np.einsum("kni,knj->nij", w, w)
    d = np.sqrt(np.clip(np.einsum("nii->ni", cov), 0.0, None))
    pv = np.sqrt(np.where(np.isfinite(place_var), np.clip(place_var, 0.0, None), 0.0))
    f = np.divide(pv, d, out=np.zeros_like(pv), where=d > 0)  # 1 where the weights agree (no failed placement)
    return cov * f[:, :, None] * f[:, None, :]


def _placement_correction(sim: _Sim, scen: Scenario, sd: float) -> dict[str, Any]:
    """Expected-placement correction: per trial, the mean features of its plan over the placements of the task's
    scatter (:meth:`~besdrake.diagnosis.trials.PlacementScatter.points`, the same for every plan, around the scenario's
    own placement) minus the features with the object at that placement. Stored in ``sim.shift`` / ``sim.full_shift``
    so that every simulated feature vector is the *expected* one of a lab whose placement scatters (a trial that is
    nonlinear in the placement does not average it out). The draws are kept (``sim.placement_draws``): a candidate
    that sets the placement itself is averaged over the same draws around its own placement instead (the correction
    depends strongly on where the object sits). Returns a summary (mean shift per group) for the notes; needs
    ``sim.layouts`` and the nominal in the cache."""
    scatter = sim.model.scatter
    if sd <= 0 or scatter is None:
        return {}
    habit = dict(scen.effects.get(scatter.effect, {}))
    d = scatter.points(sd)
    # The scatter of each trial over the placements (the task's quadrature rule; the centre first).
    q, w = scatter.quadrature(sd)
    draws = [{scatter.effect: scatter.placed(habit, dk)} for dk in d] + [{scatter.effect: scatter.placed(habit, dk)} for dk in q[1:]]
    rows = range(len(sim.plans))
    outs = sim.outcomes([{}] + draws, rows)
    feat = sim.model.simulated_features
    feats = np.array([[feat(o, sim.layouts[i]) for i, o in zip(rows, per)] for per in outs])
    full = np.array([[feat(o, sim.full_layouts[i]) for i, o in zip(rows, per)] for per in outs[: 1 + len(d)]])
    k = 1 + len(d)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        shift = np.nanmean(feats[1:k], axis=0) - feats[0]
        full_shift = np.nanmean(full[1:], axis=0) - full[0]
        gh = np.concatenate([feats[:1], feats[k:]])  # the centre and the quadrature's other placements
        ok = np.isfinite(gh)
        ww = np.where(ok, w[:, None, None], 0.0)
        ww = ww / ww.sum(axis=0)  # a placement whose rollout failed is left out (NaN where all did)
        g0 = np.where(ok, gh, 0.0)
        mean = np.sum(ww * g0, axis=0)
        place_var = np.sum(ww * np.where(ok, (g0 - mean) ** 2, 0.0), axis=0)
    sim.place_var = np.where(np.isfinite(place_var), place_var, np.nan)
    sim.place_cov = _placement_cov(np.where(ok, g0 - mean, 0.0), ww, place_var)
    sim.shift = np.where(np.isfinite(shift), shift, 0.0)
    sim.full_shift = np.where(np.isfinite(full_shift), full_shift, 0.0)
    sim.placement_draws, sim.placement_habit = d, habit
    sim.expand_all = settings.EXPAND_ALL
    return {g: np.round(np.mean(sim.full_shift[:, s_], axis=0), 4).tolist() for g, s_ in sim.model.slices().items() if g != "joints"}
