"""Fit candidate effects to the measured features: sensitivities, bounded Gauss-Newton, BIC.

The per-trial features (the task's :class:`~besdrake.diagnosis.trials.TrialModel`) are smooth functions of the effect
parameters. One finite-difference Jacobian at nominal, built from one batch of rollouts per parameter,
serves every candidate (single effects and pairs): each candidate is first fitted on that linear model
(bounded least squares, :func:`scipy.optimize.lsq_linear`), then the best few are refined with real rollouts
(Gauss-Newton steps on a Broyden-updated Jacobian, within the effect's realistic bounds). The weighted
residuals use the measurement noise per feature group, so ``chi2`` is -2 log-likelihood up to a constant
and candidates are compared by BIC = chi2 + k_eff ln n. Optionally (``linear_fit(..., select=True)``) an extended
BIC = chi2 + k ln n + 2 ln C(m, k) per effect (Chen & Chen 2008): a realistic deviation usually moves one or two of
an effect's m parameters (one joint's encoder zero, the base's height), so each candidate fits only the parameters a
forward selection on the linear model activates (the others stay nominal), and choosing k of m parameters is charged
2 ln C(m, k). It is off by default: on the hidden-effect benchmark it named one-joint offsets right where BIC lost
them to a catch-all, but lost as many other trials to "effect + object" pairs (seed 0: 17/27 right vs 19/27; seed 1,
with the 2-parameter effects fitted whole: 3/7 vs 4/7). Those pairs were mostly the object's placement scatter, which
:func:`besdrake.diagnosis.core.diagnose` now models (expected trial over the scatter); with it, ``diagnose`` turns the
selection on (``core.SELECT_PARAMETERS``): the two one-joint-offset trials that BIC lost to a catch-all were named
right and eight previously right trials stayed right (seed 0, full logs). Effects of at most :data:`DENSE_PARAMS`
parameters are fitted whole (a deviation may well move both, and a cheaper small effect would become a catch-all). A six-parameter effect of which one parameter
is off then costs about what a one-parameter effect costs, instead of losing to a small catch-all effect.
Parameter standard errors come from the Gauss-Newton covariance sigma^2 (J^T W J)^-1 at the optimum.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np
from scipy import sparse
from scipy.linalg import solve_triangular
from scipy.optimize import lsq_linear

from besdrake.sim.effects import EffectError, get_effect

#: Finite-difference step as a fraction of a parameter's realistic range (high - low).
STEP_FRACTION = 0.05
#: Parameters not fitted because they are degenerate with another of the same effect
#: (drag depends on rho * cd only; cd is fitted at the nominal air density).
DEGENERATE = {("air_drag", "rho"): "only the product rho * cd matters; cd is fitted at the nominal air density"}
#: Weak Gaussian prior on each parameter: SD = this fraction of its range around the nominal value.
PRIOR_FRACTION = 0.5
#: Effects with at most this many (observable) parameters are always fitted whole; larger ones by forward selection.
DENSE_PARAMS = 2
#: A rival's Gauss-Newton iteration (:func:`refine` with ``chi2_floor``) continues only while it gains at least this
#: fraction of its chi2 above the better candidate's (and ``min_gain``): the learn run's diagnosis refined rivals
#: 400,000-580,000 chi2 behind the cause for up to 8 rounds of rollouts for gains of a few chi2.
FLOOR_GAIN_FRACTION = 1e-3


@dataclass(frozen=True)
class ParamSpec:
    """One fitted parameter: effect, name, nominal value, bounds, finite-difference step (signed), unit; ``order``: the
    effect's ordered parameter pairs ``(lower, upper)`` (e.g. dynamic friction below static friction)."""

    effect: str
    name: str
    nominal: float
    low: float
    high: float
    step: float
    unit: str
    order: tuple[tuple[str, str], ...] = ()

    @property
    def key(self) -> str:
        return f"{self.effect}.{self.name}"

    @property
    def stays_below(self) -> bool:
        """The parameter is bounded above by another of its effect (it is stepped down, never across)."""
        return any(low == self.name for low, _ in self.order)


def param_specs(effect_names: Sequence[str], ordered: dict[tuple[str, str], str] | None = None) -> tuple[list[ParamSpec], list[str]]:
    """Parameter specs of the effects and notes on parameters left out. ``ordered``: ``{(effect, param): other}``, a
    parameter that must stay at or below another of its effect (the task's
    :attr:`~besdrake.diagnosis.trials.TrialModel.ordered_params`; default: the default task's)."""
    if ordered is None:
        from besdrake.diagnosis.trials import default_model

        ordered = default_model().ordered_params
    specs, notes = [], []
    for e in effect_names:
        eff = get_effect(e)
        order = tuple((name, up) for (eff_name, name), up in ordered.items() if eff_name == e)
        for name, p in eff.params.items():
            if (e, name) in DEGENERATE:
                notes.append(f"{e}.{name}: {DEGENERATE[(e, name)]}")
                continue
            h = STEP_FRACTION * (p.high - p.low)
            step = h if p.nominal + h <= p.high else -h
            spec = ParamSpec(e, name, p.nominal, p.low, p.high, step, p.unit, order)
            if spec.stays_below:
                spec = replace(spec, step=-abs(h))  # keep it below the parameter that bounds it
            specs.append(spec)
    return specs, notes


def effects_from(specs: Sequence[ParamSpec], theta: np.ndarray) -> dict[str, dict[str, float]]:
    """``{effect: {param: value}}`` for parameter values ``theta``, made valid for the effect (e.g. friction order)."""
    out: dict[str, dict[str, float]] = {}
    for s, v in zip(specs, theta):
        out.setdefault(s.effect, {})[s.name] = float(np.clip(v, s.low, s.high))
    orders = {s.effect: s.order for s in specs if s.order}
    for e, vals in out.items():
        try:
            get_effect(e).complete(vals)
        except EffectError:
            if e not in orders:
                raise
            for low, up in orders[e]:  # a lower parameter above its upper one: the upper follows
                vals[up] = max(vals.get(up, get_effect(e).params[up].nominal), vals.get(low, 0.0))
    return out


@dataclass
class Sensitivity:
    """Features at nominal ``y0`` (N, F) and their finite-difference derivatives ``dy`` (P, N, F) per parameter."""

    specs: list[ParamSpec]
    y0: np.ndarray
    dy: np.ndarray

    def column(self, i: int) -> np.ndarray:
        return self.dy[i]


def compute_sensitivity(specs: list[ParamSpec], y0: np.ndarray, simulate: Callable[[list[dict]], np.ndarray]) -> Sensitivity:
    """One batch of rollouts per parameter (all trials), stepped by ``spec.step``; ``simulate`` maps a list of
    effects dicts (one per parameter) to features (P, N, F)."""
    effs = []
    for s in specs:
        theta = np.array([x.nominal for x in specs])
        theta[specs.index(s)] += s.step
        effs.append(effects_from([s], [theta[specs.index(s)]]))
    ys = simulate(effs)
    dy = (ys - y0[None]) / np.array([s.step for s in specs])[:, None, None]
    dy[~np.isfinite(dy)] = 0.0
    return Sensitivity(specs=specs, y0=y0, dy=dy)


def sensitivity_at(specs: list[ParamSpec], base: dict[str, dict[str, float]], y_base: np.ndarray,
                   simulate: Callable[[list[dict]], np.ndarray]) -> Sensitivity:
    """As :func:`compute_sensitivity`, but each parameter stepped from nominal on top of the effects ``base`` (a fitted
    cause; its simulated features ``y_base``): the sensitivities of the other effects where the cause has put the robot
    (one batch of rollouts per parameter). ``specs`` must not belong to an effect of ``base``."""
    effs = [{**base, **effects_from([s], [s.nominal + s.step])} for s in specs]
    ys = simulate(effs) if effs else np.zeros((0,) + y_base.shape)
    dy = (ys - y_base[None]) / np.array([s.step for s in specs])[:, None, None]
    dy[~np.isfinite(dy)] = 0.0
    return Sensitivity(specs=specs, y0=y_base, dy=dy)


@dataclass
class CandidateFit:
    """The fit of one candidate (a set of effects) to the data."""

    effects: tuple[str, ...]
    specs: list[ParamSpec]
    theta: np.ndarray
    stderr: np.ndarray
    chi2: float
    n: int
    k: int
    refined: bool = False
    chi2_groups: dict[str, float] = field(default_factory=dict)
    unobservable: list[str] = field(default_factory=list)
    y_fit: np.ndarray | None = None  # simulated features at theta (N, F) when refined
    jac: np.ndarray | None = None  # weighted Jacobian rows (used for the covariance)
    fresh_jacobian: bool = False  # stderr from a finite-difference Jacobian at the optimum (else Broyden's)
    selection_penalty: float = 0.0  # 2 sum_e ln C(m_e, k_e): the cost of choosing the active parameters
    inactive: list[str] = field(default_factory=list)  # observable parameters left at nominal by the selection

    @property
    def k_eff(self) -> float:
        """Effective number of parameters: trace of the hat matrix of the (weak-prior) Gauss-Newton fit, so a
        parameter the data do not constrain (prior-dominated) counts ~0 and a well-determined one ~1."""
        if not self.specs or self.jac is None or self.jac.shape[1] == 0:
            return 0.0
        A = self.jac
        P, _ = _prior_rows(self.specs, self.theta)
        AtA = A.T @ A
        try:
            return float(np.trace(np.linalg.solve(AtA + P.T @ P, AtA)))
        except np.linalg.LinAlgError:
            return float(self.k)

    @property
    def bic(self) -> float:
        """Extended BIC = chi2 + k_eff ln n + the parameter-selection penalty (see :attr:`k_eff`, :func:`linear_fit`)."""
        return float(self.chi2 + self.k_eff * np.log(max(self.n, 1)) + self.selection_penalty)

    @property
    def name(self) -> str:
        return " + ".join(self.effects) if self.effects else "none (nominal simulation)"

    def parameters(self) -> dict[str, dict[str, float]]:
        return effects_from(self.specs, self.theta)

    def parameter_table(self) -> list[dict]:
        """Fitted values with standard errors; ``constrained`` is False when the data add little to the weak
        prior (standard error above half the prior SD): the value is then not determined by the log."""
        return [
            {"effect": s.effect, "parameter": s.name, "value": float(v), "stderr": float(e), "nominal": s.nominal, "low": s.low, "high": s.high, "unit": s.unit,
             "at_bound": bool(np.isclose(v, s.low) or np.isclose(v, s.high)), "constrained": bool(e < 0.5 * PRIOR_FRACTION * (s.high - s.low)),
             "stderr_source": "finite differences at the optimum" if self.fresh_jacobian else "quasi-Newton (Broyden) Jacobian"}
            for s, v, e in zip(self.specs, self.theta, self.stderr)
        ]


class Problem:
    """The data of a fit: measured features, nominal features, weights, and which entries are usable.

    ``cov``: per trial the covariance of its features (N, F, F, :meth:`~besdrake.diagnosis.noise.NoiseModel.covariances`;
    its diagonal ``sd**2``): residuals and Jacobians are then whitened per trial with the Cholesky factor of the
    correlation of its usable entries (generalised least squares), so that chi2 is -2 log-likelihood of correlated
    noise; None: every entry independent (the diagonal model). The weighted vector keeps one entry per usable entry,
    trial by trial (``np.nonzero(mask)[0]`` names each entry's trial in both models)."""

    def __init__(self, y_meas: np.ndarray, y0: np.ndarray, sd: np.ndarray, rows: np.ndarray | None = None, cov: np.ndarray | None = None) -> None:
        self.y_meas = y_meas
        self.y0 = y0
        sd = np.asarray(sd, float)
        # SD per entry (N, F): a per-feature vector is the same for every trial.
        self.sd = np.broadcast_to(sd if sd.ndim == 2 else sd[None, :], y_meas.shape)
        self.rows = np.arange(len(y_meas)) if rows is None else np.asarray(rows)
        mask = np.isfinite(y_meas) & np.isfinite(y0)
        keep = np.zeros(len(y_meas), bool)
        keep[self.rows] = True
        self.mask = mask & keep[:, None]
        self.n = int(self.mask.sum())
        self.cov = cov
        self._L = self._W = None  # block-diagonal Cholesky factors of the trials' correlations and their inverses
        self._group_W: dict[tuple[int, int], sparse.csr_matrix] = {}
        if cov is not None:
            self._L, self._W = self._blocks(slice(0, y_meas.shape[1]))

    def _blocks(self, s: slice) -> tuple[sparse.csr_matrix, sparse.csr_matrix]:
        """Block-diagonal (one block per trial, in the order of the usable entries) Cholesky factors of the correlation
        of each trial's usable entries among the columns ``s``, and their inverses."""
        Ls, Ws = [], []
        for i in np.nonzero(self.mask[:, s].any(axis=1))[0]:
            cols = np.arange(s.start, s.stop)[self.mask[i, s]]
            L = _chol_corr(self.cov[i], self.sd[i], cols)
            Ls.append(L)
            Ws.append(solve_triangular(L, np.eye(len(cols)), lower=True))
        return sparse.block_diag(Ls, format="csr"), sparse.block_diag(Ws, format="csr")

    def _whiten(self, z: np.ndarray) -> np.ndarray:
        """Standardised entries (N, F) -> the weighted vector (whitened per trial when ``cov`` is set)."""
        if self.cov is None:
            return z[self.mask]
        return self._W @ z[self.mask] if self.n else np.zeros(0)

    def weighted(self, y_sim: np.ndarray) -> np.ndarray:
        """Weighted residuals (measured - simulated) / sd on the usable entries (whitened per trial with ``cov``); NaN
        sims count as huge."""
        z = (self.y_meas - y_sim) / self.sd
        z = np.where(np.isfinite(z), z, 1e3)
        return self._whiten(z)

    def weighted_jac(self, dy: np.ndarray) -> np.ndarray:
        """Weighted Jacobian of the residual entries (n, P) from feature derivatives (P, N, F)."""
        if not len(dy):
            return np.zeros((self.n, 0))
        Z = np.stack([(d / self.sd)[self.mask] for d in dy], axis=1)
        return Z if self.cov is None else self._W @ Z

    def unweighted(self, v: np.ndarray) -> np.ndarray:
        """The feature-space array (N, F; 0 off the usable entries) of a weighted vector (the inverse of :meth:`weighted_jac`'s map)."""
        out = np.zeros(self.y_meas.shape)
        out[self.mask] = (v if self.cov is None else self._L @ v) * self.sd[self.mask]
        return out

    def group_chi2(self, z: np.ndarray, cols_of: slice) -> float:
        """chi2 of the standardised residuals ``z`` (N, F) on one group's columns: with ``cov``, each trial's entries
        whitened by the group's own block (its marginal covariance)."""
        m = self.mask[:, cols_of]
        if self.cov is None:
            v = z[:, cols_of][m]
            return float(np.sum(v * v))
        key = (cols_of.start, cols_of.stop)
        if key not in self._group_W:
            self._group_W[key] = self._blocks(cols_of)[1]
        w = self._group_W[key] @ z[:, cols_of][m]
        return float(w @ w)


def _chol_corr(cov: np.ndarray, sd: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of the correlation of ``cov`` on ``cols`` (eigenvalues clipped at 1e-6 if it is not positive definite)."""
    s = sd[cols]
    R = cov[np.ix_(cols, cols)] / np.outer(s, s)
    try:
        return np.linalg.cholesky(R)
    except np.linalg.LinAlgError:
        ev, V = np.linalg.eigh((R + R.T) / 2)
        return np.linalg.cholesky((V * np.clip(ev, 1e-6, None)) @ V.T)


def _prior_rows(specs: list[ParamSpec], theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    sd = np.array([PRIOR_FRACTION * (s.high - s.low) for s in specs])
    nominal = np.array([s.nominal for s in specs])
    return np.diag(1.0 / sd), (nominal - theta) / sd


def effect_columns(prob: "Problem", sens: "Sensitivity", effect: str):
    """The parameters of ``effect`` in ``sens``, their whitened sensitivity columns and prior rows at nominal
    (``(specs, A, P)``), or None where ``sens`` has none of them."""
    idx = [j for j, s_ in enumerate(sens.specs) if s_.effect == effect]
    if not idx:
        return None
    specs = [sens.specs[j] for j in idx]
    P, _ = _prior_rows(specs, np.array([s_.nominal for s_ in specs]))
    return specs, prob.weighted_jac(sens.dy[idx]), P


def _solve_step(A: np.ndarray, r: np.ndarray, specs: list[ParamSpec], theta: np.ndarray) -> np.ndarray:
    """Bounded least-squares step delta minimising |r - A delta|^2 + prior, theta + delta within bounds."""
    P, b = _prior_rows(specs, theta)
    M = np.vstack([A, P])
    rhs = np.concatenate([r, b])
    lo = np.array([s.low for s in specs]) - theta
    hi = np.array([s.high for s in specs]) - theta
    lo, hi = np.minimum(lo, 0.0), np.maximum(hi, 0.0)
    hi = np.where(hi <= lo, lo + 1e-12, hi)
    return lsq_linear(M, rhs, bounds=(lo, hi), method="bvls" if M.shape[1] <= 12 else "trf").x


def stderr_from(A: np.ndarray, specs: list[ParamSpec]) -> np.ndarray:
    """Standard errors from the weighted Jacobian (Gauss-Newton covariance, with the weak prior)."""
    if A.shape[1] == 0:
        return np.zeros(0)
    P, _ = _prior_rows(specs, np.array([s.nominal for s in specs]))
    H = A.T @ A + P.T @ P
    try:
        return np.sqrt(np.clip(np.diag(np.linalg.inv(H)), 0.0, None))
    except np.linalg.LinAlgError:
        return np.full(len(specs), np.inf)


def chi2_by_group(prob: Problem, y_sim: np.ndarray, slices: dict[str, slice]) -> dict[str, float]:
    """chi2 per group (each group's entries whitened by its own covariance block when the problem has one)."""
    z = (prob.y_meas - y_sim) / prob.sd
    z = np.where(np.isfinite(z), z, 1e3)
    return {g: prob.group_chi2(z, s) for g, s in slices.items() if prob.mask[:, s].any()}


def selection_penalty(specs: Sequence[ParamSpec], n_params: dict[str, int]) -> float:
    """2 sum over effects of ln C(m_e, k_e): the cost of having chosen k_e of an effect's m_e parameters."""
    from math import comb, log

    k: dict[str, int] = {}
    for s_ in specs:
        k[s_.effect] = k.get(s_.effect, 0) + 1
    return float(sum(2.0 * log(comb(n_params[e], c)) for e, c in k.items() if n_params.get(e, 0) >= c))


def linear_fit(prob: Problem, sens: Sensitivity, effects: tuple[str, ...], observable_tol: float = 1e-3, select: bool = False) -> CandidateFit:
    """Fit a candidate on the linear model at nominal (no rollouts).

    ``select``: forward selection of the active parameters (at least one per effect), ranked by the extended BIC
    chi2 + k ln n + 2 sum ln C(m_e, k_e); unselected parameters stay nominal (``inactive``). Without it every
    observable parameter is fitted.
    """
    idx = [i for i, s in enumerate(sens.specs) if s.effect in effects]
    A_all = prob.weighted_jac(sens.dy[idx]) if idx else np.zeros((prob.n, 0))
    scale = np.array([abs(s.high - s.low) for s in (sens.specs[i] for i in idx)])
    norms = np.linalg.norm(A_all, axis=0) * scale if idx else np.zeros(0)
    keep = [j for j, nrm in enumerate(norms) if nrm > observable_tol * max(1.0, np.sqrt(prob.n))]
    unobs = [sens.specs[idx[j]].key for j in range(len(idx)) if j not in keep]
    n_params = {e: sum(1 for j in keep if sens.specs[idx[j]].effect == e) for e in effects}
    r0 = prob.weighted(sens.y0)
    ln_n = np.log(max(prob.n, 1))

    def solve(cols: list[int]):
        sp = [sens.specs[idx[j]] for j in cols]
        A = A_all[:, cols]
        th0 = np.array([s_.nominal for s_ in sp])
        if not sp:
            return sp, A, th0, np.zeros(0), float(r0 @ r0)
        delta = _solve_step(A, r0, sp, th0)
        r = r0 - A @ delta
        return sp, A, th0, delta, float(r @ r)

    chosen = list(keep)
    # Effects with at most DENSE_PARAMS parameters are fitted whole (a realistic deviation may move both); the
    # selection only picks among the parameters of larger effects (base pose, six encoder offsets).
    dense = [j for j in keep if n_params[sens.specs[idx[j]].effect] <= DENSE_PARAMS]
    free = [j for j in keep if j not in dense]
    if select and free:
        active: list[int] = list(dense)
        best_crit, best_set = np.inf, list(keep)
        remaining = list(free)
        while remaining:
            trials = [(solve(active + [j])[4], j) for j in remaining]
            c2, j = min(trials)
            active.append(j)
            remaining.remove(j)
            sp = [sens.specs[idx[x]] for x in active]
            if all(any(s_.effect == e for s_ in sp) for e in effects if n_params.get(e, 0) > 0):
                crit = c2 + len(active) * ln_n + selection_penalty(sp, n_params)
                if crit < best_crit - 1e-9:
                    best_crit, best_set = crit, list(active)
        chosen = sorted(best_set)
    specs, A, theta0, delta, c2 = solve(chosen)
    inactive = [sens.specs[idx[j]].key for j in keep if j not in chosen]
    return CandidateFit(effects=effects, specs=specs, theta=theta0 + delta, stderr=stderr_from(A, specs), chi2=c2, n=prob.n, k=len(specs),
                        unobservable=unobs, jac=A, selection_penalty=selection_penalty(specs, n_params) if select else 0.0, inactive=inactive)


def refine(
    prob: Problem,
    fit: CandidateFit,
    simulate_one: Callable[[dict], np.ndarray],
    iterations: int = 5,
    starts: Sequence[tuple[np.ndarray, np.ndarray]] = (),
    try_linear: bool = True,
    min_gain: float = 0.5,
    nominal_secants: bool = True,
    chi2_floor: float | None = None,
) -> CandidateFit:
    """Gauss-Newton with real rollouts: Broyden-updated Jacobian, step halving, bounded steps.

    ``simulate_one(effects) -> features (N, F)``. The start is the best (real chi2) of the nominal, the
    linear solution (``try_linear``: one batch of rollouts) and ``starts``: already simulated
    ``(theta, y_sim)`` pairs, e.g. a refined single effect for a pair. Stops when an iteration lowers chi2
    by less than ``min_gain`` or after ``iterations``. ``nominal_secants``: update the Jacobian with the secants from
    the nominal to each start (off when ``fit.jac`` is already a local Jacobian at a start, as in a forward step).
    ``chi2_floor``: the chi2 of a better candidate (a rival's refinement): an iteration must then also gain
    :data:`FLOOR_GAIN_FRACTION` of the candidate's distance above it, so a rival thousands of chi2 behind stops once
    its steps no longer close that gap materially, and one near the floor is refined to ``min_gain`` as any other.
    """
    if not fit.specs:
        y = simulate_one({})
        r = prob.weighted(y)
        fit.chi2, fit.refined, fit.y_fit = float(r @ r), True, y
        return fit
    specs = fit.specs
    A, theta, y, r = _best_start(prob, fit, simulate_one, starts, try_linear, nominal_secants)
    ranges = np.array([s.high - s.low for s in specs])
    for _ in range(iterations):
        delta = _solve_step(A, r, specs, theta)
        if np.max(np.abs(delta) / ranges) < 1e-7:
            break
        A, theta, y, r, improved = _halving_step(prob, specs, simulate_one, A, theta, y, r, delta, min_gain, chi2_floor)
        if not improved:
            break
    fit.theta, fit.chi2, fit.refined, fit.y_fit, fit.jac = theta, float(r @ r), True, y, A
    fit.stderr = stderr_from(A, specs)
    return fit


def warm_start(specs: list[ParamSpec], sub: CandidateFit, simulate_one: Callable[[dict], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """A start ``(theta, y_sim)`` for a candidate with ``specs`` from the refined candidate ``sub`` it contains: ``sub``'s
    values where ``specs`` hold its parameters, nominal elsewhere. ``sub``'s own predictions are reused only where they
    are the start's (every parameter ``sub`` moved is among ``specs``); otherwise the start is simulated (one batch).

    Why: a pair's parameter selection may drop parameters its single effect moved (the single fits six encoder offsets,
    the pair two of them and the object's size); reusing the single's predictions then pairs a point with a residual it
    does not have, the pair is credited with the single's chi2 at fewer parameters, and every Broyden update against
    that residual corrupts its Jacobian (diagnosis benchmark trial 15: the pair of the hidden object size and joint offset stalled at
    chi2 830 against the single's 597)."""
    keys = [s_.key for s_ in specs]
    th = np.array([s_.nominal for s_ in specs])
    dropped = False
    for s_, v in zip(sub.specs, sub.theta):
        if s_.key in keys:
            th[keys.index(s_.key)] = v
        elif v != s_.nominal:
            dropped = True
    return th, (simulate_one(effects_from(specs, th)) if dropped else sub.y_fit)


def _best_start(prob: Problem, fit: CandidateFit, simulate_one: Callable[[dict], np.ndarray],
                starts: Sequence[tuple[np.ndarray, np.ndarray]], try_linear: bool, nominal_secants: bool):
    """:func:`refine`'s start: the Jacobian with the secants from the nominal to every start point, and the start point
    (theta, y, weighted residual) of the smallest chi2 among the nominal, the linear solution and ``starts``."""
    specs = fit.specs
    A = fit.jac.copy()
    theta_nom = np.array([s.nominal for s in specs])
    r_nom = prob.weighted(prob.y0)
    points = [(theta_nom, prob.y0, r_nom)]
    if try_linear and np.any(fit.theta != theta_nom):
        y_lin = simulate_one(effects_from(specs, fit.theta))
        points.append((fit.theta.copy(), y_lin, prob.weighted(y_lin)))
    for th, y in starts:
        points.append((np.asarray(th, float), y, prob.weighted(y)))
    # Secant information from every start point (rank-one updates from the nominal).
    for th, _y, r_p in (points[1:] if nominal_secants else []):
        dth = th - theta_nom
        if np.any(dth):
            A = A + np.outer((r_nom - r_p) - A @ dth, dth) / (dth @ dth)
    theta, y, r = min(points, key=lambda p: float(p[2] @ p[2]))
    return A, theta.copy(), y, r


def _halving_step(prob: Problem, specs: list[ParamSpec], simulate_one: Callable[[dict], np.ndarray], A: np.ndarray,
                  theta: np.ndarray, y: np.ndarray, r: np.ndarray, delta: np.ndarray, min_gain: float,
                  chi2_floor: float | None):
    """One Gauss-Newton step of :func:`refine` with up to three halvings, the Jacobian Broyden-updated after every
    rollout; returns (A, theta, y, r, improved): improved when a step gained at least ``min_gain`` (and, with a
    ``chi2_floor``, FLOOR_GAIN_FRACTION of the gap above it)."""
    for _half in range(3):
        cand = theta + delta
        y_c = simulate_one(effects_from(specs, cand))
        r_c = prob.weighted(y_c)
        # Broyden rank-one update with the observed change of the residuals.
        A = A + np.outer((r - r_c) - A @ delta, delta) / (delta @ delta)
        if r_c @ r_c < r @ r:
            gain = float(r @ r - r_c @ r_c)
            gap = 0.0 if chi2_floor is None else max(0.0, float(r_c @ r_c) - chi2_floor)
            return A, cand, y_c, r_c, gain >= max(min_gain, FLOOR_GAIN_FRACTION * gap)
        delta = 0.5 * delta
    return A, theta, y, r, False


def jacobian_at(prob: Problem, fit: CandidateFit, simulate: Callable[[list[dict]], np.ndarray]) -> CandidateFit:
    """Replace the (Broyden-updated) Jacobian of a refined fit by a fresh finite-difference one at its optimum
    (one batch of rollouts per parameter) and recompute the standard errors from it."""
    if not fit.specs or fit.y_fit is None:
        return fit
    effs, steps = [], []
    for j, s in enumerate(fit.specs):
        th = fit.theta.copy()
        h = 0.5 * abs(s.step)
        h = h if th[j] + h <= s.high else -h
        if s.stays_below:
            h = -abs(h)
        th[j] += h
        effs.append(effects_from(fit.specs, th))
        steps.append(h)
    ys = simulate(effs)
    dy = (ys - fit.y_fit[None]) / np.array(steps)[:, None, None]
    dy[~np.isfinite(dy)] = 0.0
    fit.jac = prob.weighted_jac(dy)
    fit.stderr = stderr_from(fit.jac, fit.specs)
    fit.fresh_jacobian = True
    return fit


def candidate_sets(effects: Sequence[str], pairs: bool = True) -> list[tuple[str, ...]]:
    """The empty set, every single effect and (optionally) every pair."""
    out: list[tuple[str, ...]] = [()]
    out += [(e,) for e in effects]
    if pairs:
        out += list(itertools.combinations(effects, 2))
    return out


__all__ = ["ParamSpec", "param_specs", "selection_penalty", "effects_from", "Sensitivity", "compute_sensitivity", "CandidateFit", "Problem", "linear_fit", "refine", "candidate_sets", "chi2_by_group"]
