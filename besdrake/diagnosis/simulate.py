"""Simulated features of the logged plans: batched, memoised rollouts (:class:`Simulator`) and the expected throw over
the lab's ball-placement scatter (:func:`placement_correction`)."""

from __future__ import annotations

import json
import warnings
from typing import Any, Sequence

import numpy as np

from besdrake.diagnosis import observables, settings
from besdrake.diagnosis.observables import group_slices
from besdrake.tasks.throwing.effects import ball_placed, placement_quadrature
from besdrake.sim.scenario import Scenario


class _Sim:
    """Batches rollouts through an executor and turns Outcomes into features.

    Repeated plans are simulated once per parameter set, and Outcomes are memoised by (plan hash, effects)
    in ``cache`` (a dict the caller may share between diagnoses of the same throws, e.g. a full and a
    touchdown-only view of one log). ``n_rollouts`` counts the rollouts actually run.
    """

    def __init__(self, executor, plans, keys, layouts, full_layouts, cache: dict | None = None):
        self.ex, self.plans, self.keys, self.layouts, self.full_layouts = executor, plans, keys, layouts, full_layouts
        self.n_rollouts = 0
        self.cache: dict = {} if cache is None else cache
        self.full_cache: dict[str, np.ndarray] = {}
        # Expected-placement corrections (N, F) added to every simulated feature vector (zeros: none).
        self.shift = np.zeros((len(plans), observables.N_FEATURES))
        self.full_shift = np.zeros((len(plans), observables.N_FEATURES))
        # Predicted placement variance per throw and feature (None: the lab's placement does not scatter).
        self.place_var: np.ndarray | None = None
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
        """The effects dicts whose mean is this candidate's expected throw: the placement draws around the
        candidate's own placement when it sets ``ball_placement`` (and draws are set), else the candidate itself."""
        if self.placement_draws is None or ("ball_placement" not in effects and not (self.expand_all and effects)):
            return [effects]
        own = {**self.placement_habit, **effects.get("ball_placement", {})}
        out = []
        for d in self.placement_draws:
            e = {k: dict(v) for k, v in effects.items()}
            e["ball_placement"] = ball_placed(own, d)
            out.append(e)
        return out

    def features(self, effects_list: list[dict], rows: Sequence[int] | None = None, shift: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """Expected features (len(effects_list), N, F) with NaN rows outside ``rows``: a candidate that sets the ball's
        placement is averaged over the placement draws around it, any other gets the placement correction added: the
        nominal one (``self.shift``/``self.full_shift``) or ``shift`` = (shift, full_shift), e.g. a candidate's own
        (:meth:`local_shift`)."""
        rows = list(range(len(self.plans))) if rows is None else list(rows)
        sh, full_sh = (self.shift, self.full_shift) if shift is None else shift
        expanded = [self._expand(e) for e in effects_list]
        flat = [x for ex_ in expanded for x in ex_]
        outs = self.outcomes(flat, rows)
        Y = np.full((len(effects_list), len(self.plans), observables.N_FEATURES), np.nan)
        j = 0
        for a, e in enumerate(effects_list):
            n_e = len(expanded[a])
            ys = np.full((n_e, len(self.plans), observables.N_FEATURES), np.nan)
            fulls = np.full((n_e, len(self.plans), observables.N_FEATURES), np.nan)
            for b in range(n_e):
                for i, o in zip(rows, outs[j + b]):
                    ys[b, i] = observables.simulated_features(o, self.layouts[i])
                    fulls[b, i] = observables.simulated_features(o, self.full_layouts[i])
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
        placement draws around the scenario's placement minus the candidate with the ball there (one rollout per draw
        and throw). None when no draws are set or the candidate sets the placement itself (it is averaged exactly)."""
        if self.placement_draws is None or "ball_placement" in effects or not effects:
            return None
        draws = []
        for d in self.placement_draws:
            e = {k: dict(v) for k, v in effects.items()}
            e["ball_placement"] = ball_placed(self.placement_habit, d)
            draws.append(e)
        rows = range(len(self.plans))
        outs = self.outcomes([effects] + draws, rows)
        out = []
        for lays in (self.layouts, self.full_layouts):
            f = np.array([[observables.simulated_features(o, lays[i]) for i, o in zip(rows, per)] for per in outs])
            with np.errstate(invalid="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                sh = np.nanmean(f[1:], axis=0) - f[0]
            out.append(np.where(np.isfinite(sh), sh, 0.0))
        return out[0], out[1]


def _full_layout(layout: observables.ThrowLayout) -> observables.ThrowLayout:
    """A layout with every group (100 Hz flight window, joint grid) for predictions of unmeasured signals."""
    full = observables.ThrowLayout(ball_times=layout.ball_times, ball_center=layout.ball_center, rest_times=layout.rest_times, joint_times=layout.joint_times,
                                   release_time_nominal=layout.release_time_nominal, touchdown_time_nominal=layout.touchdown_time_nominal)
    if layout.release_time_nominal is None:
        return full
    if full.ball_times is None:
        t = np.arange(layout.release_time_nominal + observables.WINDOW_AFTER_RELEASE, layout.touchdown_time_nominal - observables.WINDOW_BEFORE_TOUCHDOWN, 0.01)
        if len(t) >= observables.MIN_BALL_SAMPLES:
            full.ball_times, full.ball_center = t, float(t.mean())
    if full.rest_times is None:
        full.rest_times = np.arange(0.0, observables.REST_TIME + 1e-9, 0.005)
    if full.joint_times is None:
        t_end = layout.release_time_nominal
        full.joint_times = np.linspace(t_end / observables.N_JOINT_TIMES, t_end, observables.N_JOINT_TIMES)
    return full


def placement_points(sd: float) -> np.ndarray:
    """The four placements (m, scoop x/y) whose mean stands for the N(0, sd^2)-per-axis scatter: (+-a, +-a) with
    a = sd sqrt(2/pi). Exact for the mean of anything linear or linear in |x| and |y| (the funnel lifts an off-centre
    ball by its distance from the centre per wall), symmetric (the linear part cancels); pure quadratic terms come out
    at 2/pi of their value. Deterministic, so that every candidate sees the same points (a smooth fit)."""
    a = sd * np.sqrt(2.0 / np.pi)
    return np.array([[a, a], [a, -a], [-a, a], [-a, -a]])


def _placement_correction(sim: _Sim, scen: Scenario, sd: float) -> dict[str, Any]:
    """Expected-placement correction: per throw, the mean features of its plan over the ball placements of
    :func:`placement_points` (the same for every plan, around the scenario's own placement) minus the features with the ball at that placement. Stored in ``sim.shift`` / ``sim.full_shift`` so
    that every simulated feature vector is the *expected* one of a lab whose ball placement scatters (the throw is
    nonlinear in the placement: the funnel lifts an off-centre ball, so the scatter does not average out). The
    draws are kept (``sim.placement_draws``): a candidate that sets the placement itself is averaged over the same
    draws around its own placement instead (the correction depends strongly on where the ball sits).
    Returns a summary (mean shift per group) for the notes; needs ``sim.layouts`` and the nominal in the cache."""
    if sd <= 0:
        return {}
    habit = dict(scen.effects.get("ball_placement", {}))
    d = placement_points(sd)
    # The scatter of each throw over the placements: the 3 x 3 Gauss-Hermite rule (exact for quadratics; the funnel's
    # kink, which the four points above all see alike, comes out larger than it is: the safe side for a weight).
    q, w = placement_quadrature(sd)
    draws = [{"ball_placement": ball_placed(habit, dk)} for dk in d] + [{"ball_placement": ball_placed(habit, dk)} for dk in q[1:]]
    rows = range(len(sim.plans))
    outs = sim.outcomes([{}] + draws, rows)
    feats = np.array([[observables.simulated_features(o, sim.layouts[i]) for i, o in zip(rows, per)] for per in outs])
    full = np.array([[observables.simulated_features(o, sim.full_layouts[i]) for i, o in zip(rows, per)] for per in outs[: 1 + len(d)]])
    k = 1 + len(d)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        shift = np.nanmean(feats[1:k], axis=0) - feats[0]
        full_shift = np.nanmean(full[1:], axis=0) - full[0]
        gh = np.concatenate([feats[:1], feats[k:]])  # the centre and the quadrature's other 8 placements
        ok = np.isfinite(gh)
        ww = np.where(ok, w[:, None, None], 0.0)
        ww = ww / ww.sum(axis=0)  # a placement that did not land is left out (NaN where none did)
        g0 = np.where(ok, gh, 0.0)
        mean = np.sum(ww * g0, axis=0)
        place_var = np.sum(ww * np.where(ok, (g0 - mean) ** 2, 0.0), axis=0)
    sim.place_var = np.where(np.isfinite(place_var), place_var, np.nan)
    sim.shift = np.where(np.isfinite(shift), shift, 0.0)
    sim.full_shift = np.where(np.isfinite(full_shift), full_shift, 0.0)
    sim.placement_draws, sim.placement_habit = d, habit
    sim.expand_all = settings.EXPAND_ALL
    return {g: np.round(np.mean(sim.full_shift[:, s_], axis=0), 4).tolist() for g, s_ in group_slices().items() if g != "joints"}
