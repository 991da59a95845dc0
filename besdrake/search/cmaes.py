"""CMA-ES (Hansen & Ostermeier 2001) through the ``cma`` package, behind the ask/tell interface.

* Maximises: rewards are negated before they reach ``cma`` (which minimises).
* Randomness: ``cma`` draws its standard-normal samples through its ``randn`` option, which this
  wrapper points at the ``numpy.random.Generator`` given at construction (``cma``'s own ``seed``
  option is set to "do nothing", so the global ``numpy.random`` state is never touched). The
  Generator's state is therefore the whole random state of a run.
* Bounds: ``cma``'s ``bounds`` option (its default boundary handling, a smooth transformation into
  the box), so every candidate lies inside the bounds.
* Restarts: optional IPOP or BIPOP restarts (Hansen 2009, "Benchmarking a BI-population CMA-ES on
  the BBOB-2009 function testbed"), scheduled by this wrapper, not by ``cma.fmin``. When a run
  stops (``cma``'s termination criteria), the next run starts again from ``x0``:

  - *large regime* (IPOP): population ``popsize0 * 2**k`` after ``k`` large restarts, step size
    ``sigma0``;
  - *small regime* (BIPOP only): population ``floor(popsize0 * (popsize_large / (2 popsize0))**(u**2))``
    and step size ``sigma0 * 10**(-2 u)`` with ``u ~ U(0, 1)``, where ``popsize_large`` is the
    population of the last large run;
  - BIPOP picks the small regime whenever the evaluations spent in small runs are fewer than those
    spent in large runs (the first run counts as large), the large regime otherwise.

* Save/resume without pickle: :meth:`CMAES.state_dict` stores the distribution (mean, step size,
  covariance ``C`` and its eigendecomposition ``B``, ``D``), the evolution paths ``pc`` and ``ps``,
  the iteration/evaluation/eigendecomposition counters, the fitness histories that ``cma``'s
  termination criteria read, the restart bookkeeping and the Generator state. A resumed optimizer
  asks exactly the same candidates as the uninterrupted one (tested). What is approximate: the
  internal record of ``cma``'s ``tolstagnation``/``tolxstagnation`` checks and its logger are
  rebuilt from the saved histories, so a resumed run may stop at a slightly different generation
  than an uninterrupted one would.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cma
import numpy as np

from besdrake.search.base import BestAndWorst, Optimizer, rng_from_state, rng_state

_RESTART_STRATEGIES = ("none", "ipop", "bipop")
#: Restart regimes of :class:`StagnationRestartCMAES`.
_STAGNATION_REGIMES = ("large", "bipop", "local")

# Attributes of cma.CMAEvolutionStrategy (and its sub-objects) that change during tell() and
# determine the next candidates and the termination tests. Paths are relative to the strategy.
# "C", "B", "D", "dC", "pc2": the diagonal covariance of separable CMA-ES (cma option CMA_diagonal) lives on the strategy itself
_ARRAY_ATTRS = ("mean", "mean_old", "mean_after_tell", "pc", "pc_neg", "sm.C", "sm.B", "sm.D", "adapt_sigma.ps", "sigma_vec.scaling",
                "C", "B", "D", "dC", "pc2", "best.x", "best.x_geno")  # best.*: what elitist CMA-ES (CMA_elitist) re-injects
_SCALAR_ATTRS = (
    "sigma",
    "_sigma_old",
    "countiter",
    "countevals",
    "sm.count_tell",
    "sm.last_update",
    "sm.count_eigen",
    "sm._corr_condition",
    "sm._corr_condition_count_eigen",
    "adapt_sigma.delta",
    "adapt_sigma._last_multiplier",
    "adapt_sigma._ps_updated_iteration",
    "adapt_sigma.is_initialized",
    "fit.median",
    "fit.median0",
    "fit.median_min",
    "fit.median_previous",
    "fit.median_got_worse",
    "fit.flatfit_iterations",
    "sigma_vec.is_identity",
    "best.f",
    "best.evals",
)
_LIST_ATTRS = ("fit.hist", "fit.histbest", "fit.histmedian", "fit.fit", "hsiglist")


def _get(obj: Any, path: str) -> Any:
    for name in path.split("."):
        obj = getattr(obj, name)
    return obj


def _set(obj: Any, path: str, value: Any) -> None:
    *parents, name = path.split(".")
    for parent in parents:
        obj = getattr(obj, parent)
    setattr(obj, name, value)


def _has(obj: Any, path: str) -> bool:
    try:
        _get(obj, path)
    except AttributeError:
        return False
    return True


@dataclass
class _Run:
    """Bookkeeping of one (re)start."""

    popsize: int
    sigma0: float
    regime: str  # "large" or "small"


class CMAES(BestAndWorst, Optimizer):
    """CMA-ES maximiser with optional bounds and IPOP/BIPOP restarts.

    Parameters
    ----------
    x0, sigma0:
        Initial mean (shape ``(n_params,)``) and initial step size (> 0, in parameter units).
    rng:
        The only source of randomness.
    popsize:
        Population of the first run; ``None`` uses ``cma``'s default ``4 + floor(3 ln n)``.
    bounds:
        ``None`` or an array of shape ``(n_params, 2)`` with lower and upper bounds (``+-inf`` allowed).
    restarts:
        Number of restarts after the first run stops (0: no restarts).
    restart_strategy:
        ``"bipop"`` (default) or ``"ipop"``; ignored when ``restarts == 0``.
    tolfun, tolx:
        ``cma`` termination tolerances of one run (on reward range and step length).
    cma_options:
        Further ``cma`` options (JSON-compatible values only, so the state can be saved).
    """

    def __init__(
        self,
        x0: np.ndarray,
        sigma0: float,
        rng: np.random.Generator,
        *,
        popsize: int | None = None,
        bounds: np.ndarray | None = None,
        restarts: int = 0,
        restart_strategy: str = "bipop",
        tolfun: float = 1e-11,
        tolx: float = 1e-11,
        cma_options: dict[str, Any] | None = None,
    ) -> None:
        x0 = np.asarray(x0, dtype=float).ravel()
        if x0.size == 0 or not np.isfinite(x0).all():
            raise ValueError(f"x0 must be a non-empty finite vector, got {x0!r}")
        if not (np.isfinite(sigma0) and sigma0 > 0):
            raise ValueError(f"sigma0 must be a positive finite step size, got {sigma0!r}")
        if restart_strategy not in _RESTART_STRATEGIES:
            raise ValueError(f"restart_strategy must be one of {_RESTART_STRATEGIES}, got {restart_strategy!r}")
        if restarts < 0:
            raise ValueError(f"restarts must be >= 0, got {restarts}")
        if popsize is not None and popsize < 2:
            raise ValueError(f"popsize must be >= 2, got {popsize}")
        self.n_params = x0.size
        self.x0 = x0
        self.sigma0 = float(sigma0)
        self.rng = rng
        self.bounds = None if bounds is None else self._check_bounds(bounds, x0)
        self.restarts = int(restarts)
        self.restart_strategy = "none" if restarts == 0 else restart_strategy
        self.tolfun = float(tolfun)
        self.tolx = float(tolx)
        self.cma_options = dict(cma_options or {})
        self.popsize0 = int(popsize) if popsize is not None else 4 + int(3 * math.log(self.n_params))
        # restart bookkeeping
        self.n_restarts_done = 0
        self.n_large_restarts = 0
        self.evaluations_large = 0
        self.evaluations_small = 0
        self.n_evaluations = 0
        self.run = _Run(self.popsize0, self.sigma0, "large")
        # one entry per finished run: popsize, sigma0, regime, evaluations, best reward of the run
        self.restart_history: list[dict[str, Any]] = []
        self._run_evaluations = 0
        self._run_best = -np.inf
        self._init_best(x0)
        self._pending: np.ndarray | None = None
        self._rng_before_ask: dict[str, Any] | None = None
        self._finished = False
        self.es = self._new_strategy(self.run)

    # -- construction helpers -------------------------------------------------------------------
    @staticmethod
    def _check_bounds(bounds: np.ndarray, x0: np.ndarray) -> np.ndarray:
        bounds = np.asarray(bounds, dtype=float)
        if bounds.shape != (x0.size, 2):
            raise ValueError(f"bounds must have shape ({x0.size}, 2), got {bounds.shape}")
        if np.isnan(bounds).any() or (bounds[:, 0] >= bounds[:, 1]).any():
            raise ValueError("bounds must be ordered (lower < upper) and contain no NaN")
        if ((x0 < bounds[:, 0]) | (x0 > bounds[:, 1])).any():
            raise ValueError("x0 lies outside the bounds")
        return bounds

    def _randn(self, *shape: int) -> np.ndarray:
        return self.rng.standard_normal(shape)

    def _new_strategy(self, run: _Run) -> cma.CMAEvolutionStrategy:
        options: dict[str, Any] = {
            "seed": np.nan,  # leave numpy's global state alone: samples come from self.rng
            "randn": self._randn,
            "popsize": run.popsize,
            "verbose": -9,
            "verb_log": 0,
            "verb_disp": 0,
            "tolfun": self.tolfun,
            "tolx": self.tolx,
        }
        if self.bounds is not None:
            options["bounds"] = [list(self.bounds[:, 0]), list(self.bounds[:, 1])]
        options.update(self.cma_options)
        return cma.CMAEvolutionStrategy(self.x0.copy(), run.sigma0, options)

    # -- ask / tell ------------------------------------------------------------------------------
    def ask(self) -> np.ndarray:
        if self._pending is not None:
            return self._pending.copy()
        self._rng_before_ask = rng_state(self.rng)
        self._pending = np.array(self.es.ask(), dtype=float)
        return self._pending.copy()

    def tell(self, candidates: np.ndarray, rewards: np.ndarray) -> None:
        candidates = np.asarray(candidates, dtype=float)
        if self._pending is None or candidates.shape != self._pending.shape:
            raise ValueError("tell() needs the candidates returned by the last ask()")
        rewards, _ = self._record_batch(candidates, rewards)
        self.es.tell(list(candidates), list(-rewards))
        self._pending = None
        self._rng_before_ask = None
        self.n_evaluations += rewards.size
        self._run_evaluations += rewards.size
        self._run_best = max(self._run_best, float(rewards.max()))
        if self.run.regime == "large":
            self.evaluations_large += rewards.size
        else:
            self.evaluations_small += rewards.size
        if self.es.stop():
            self._restart_or_finish()

    def _restart_or_finish(self) -> None:
        self.restart_history.append(
            {
                "popsize": self.run.popsize,
                "sigma0": self.run.sigma0,
                "regime": self.run.regime,
                "evaluations": self._run_evaluations,
                "best_reward": self._run_best,
                "stop": {k: (float(v) if isinstance(v, (int, float, np.generic)) else str(v)) for k, v in self.es.stop().items()},
            }
        )
        self._run_evaluations = 0
        self._run_best = -np.inf
        if self.n_restarts_done >= self.restarts:
            self._finished = True
            return
        self.n_restarts_done += 1
        if self.restart_strategy == "bipop" and self.evaluations_small < self.evaluations_large:
            u = float(self.rng.uniform())
            large = self.popsize0 * 2**self.n_large_restarts
            popsize = max(2, int(self.popsize0 * (0.5 * large / self.popsize0) ** (u**2)))
            self.run = _Run(popsize, self.sigma0 * 10 ** (-2 * u), "small")
        else:
            self.n_large_restarts += 1
            self.run = _Run(self.popsize0 * 2**self.n_large_restarts, self.sigma0, "large")
        self.es = self._new_strategy(self.run)

    @property
    def mean(self) -> np.ndarray:
        """Mean of the current search distribution."""
        return np.array(self.es.mean, dtype=float)

    def stop(self) -> bool:
        return self._finished

    # -- persistence -----------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """State after the last :meth:`tell`; candidates asked but not told are asked again."""
        arrays = {path: np.array(_get(self.es, path), dtype=float) for path in _ARRAY_ATTRS if _has(self.es, path) and _get(self.es, path) is not None}
        scalars = {}
        for path in _SCALAR_ATTRS:
            if _has(self.es, path):
                value = _get(self.es, path)
                scalars[path] = value.item() if isinstance(value, np.generic) else value
        lists = {path: np.array(_get(self.es, path), dtype=float) for path in _LIST_ATTRS if _has(self.es, path)}
        return {
            "type": "CMAES",
            "config": {
                "x0": self.x0,
                "sigma0": self.sigma0,
                "popsize0": self.popsize0,
                "bounds": self.bounds if self.bounds is not None else None,
                "restarts": self.restarts,
                "restart_strategy": self.restart_strategy,
                "tolfun": self.tolfun,
                "tolx": self.tolx,
                "cma_options": self.cma_options,
            },
            "run": {"popsize": self.run.popsize, "sigma0": self.run.sigma0, "regime": self.run.regime},
            "counters": {
                "n_restarts_done": self.n_restarts_done,
                "n_large_restarts": self.n_large_restarts,
                "evaluations_large": self.evaluations_large,
                "evaluations_small": self.evaluations_small,
                "n_evaluations": self.n_evaluations,
                "finished": self._finished,
                "run_evaluations": self._run_evaluations,
                "run_best": float(self._run_best),
            },
            "restart_history": self.restart_history,
            **self._best_state(),
            "rng": self._rng_before_ask if self._rng_before_ask is not None else rng_state(self.rng),
            "es_arrays": arrays,
            "es_scalars": scalars,
            "es_lists": lists,
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "CMAES":
        if state.get("type") != "CMAES":
            raise ValueError(f"not a CMAES state (type={state.get('type')!r})")
        cfg = state["config"]
        restarts = int(cfg["restarts"])
        opt = cls(
            np.asarray(cfg["x0"]),
            cfg["sigma0"],
            rng_from_state(state["rng"]),
            popsize=cfg["popsize0"],
            bounds=None if cfg["bounds"] is None else np.asarray(cfg["bounds"]),
            restarts=restarts,
            restart_strategy=cfg["restart_strategy"] if restarts else "bipop",
            tolfun=cfg["tolfun"],
            tolx=cfg["tolx"],
            cma_options=cfg["cma_options"],
        )
        counters = state["counters"]
        opt.n_restarts_done = int(counters["n_restarts_done"])
        opt.n_large_restarts = int(counters["n_large_restarts"])
        opt.evaluations_large = int(counters["evaluations_large"])
        opt.evaluations_small = int(counters["evaluations_small"])
        opt.n_evaluations = int(counters["n_evaluations"])
        opt._finished = bool(counters["finished"])
        opt._run_evaluations = int(counters["run_evaluations"])
        opt._run_best = float(counters["run_best"])
        opt.restart_history = [dict(entry) for entry in state["restart_history"]]
        run = state["run"]
        opt.run = _Run(int(run["popsize"]), float(run["sigma0"]), str(run["regime"]))
        opt.es = opt._new_strategy(opt.run)
        for path, value in state["es_arrays"].items():
            _set(opt.es, path, np.array(value, dtype=float))
        for path, value in state["es_scalars"].items():
            _set(opt.es, path, value)
        for path, value in state["es_lists"].items():
            _set(opt.es, path, [float(v) for v in np.asarray(value).ravel()])
        if _has(opt.es, "sm._inverse_root_C"):
            opt.es.sm._inverse_root_C = None  # recomputed lazily from the restored B, D
        if opt.es.countiter > 0:  # cma creates its wall-clock timer in the first ask()
            opt.es.timer = cma.utilities.utils.ElapsedWCTime()
            opt.es.timer.pause()
            opt.es._stoptolxstagnation.update(opt.es.mean)
        opt._restore_best(state)
        return opt


class StagedCMAES(BestAndWorst, Optimizer):
    """CMA-ES first in a low-dimensional affine subspace, then in the full space (a maximiser).

    Stage 1 searches ``z`` (``k`` dimensions) with candidates ``x = clip(x0 + basis @ z, bounds)``: a few
    meta-parameters with a large effect (for the throw: joint offsets, goals, execution time) move the
    search far from ``x0`` in few episodes. After ``subspace_evaluations`` episodes (or when that CMA-ES
    stops) stage 2 runs CMA-ES on all ``n`` parameters from the best candidate of stage 1 with step size
    ``sigma_full``. ``ask`` always returns full-space candidates, so the episode log and the rewards are
    those of the full problem. One Generator drives both stages; the state (both stages, the stage
    counter) is saved and restored like :class:`CMAES` (a resumed run asks the same candidates).
    """

    def __init__(
        self,
        x0: np.ndarray,
        basis: np.ndarray,
        sigma_subspace: float,
        sigma_full: float,
        rng: np.random.Generator,
        *,
        subspace_evaluations: int,
        popsize_subspace: int | None = None,
        popsize: int | None = None,
        bounds: np.ndarray | None = None,
        cma_options: dict[str, Any] | None = None,
    ) -> None:
        x0 = np.asarray(x0, dtype=float).ravel()
        basis = np.asarray(basis, dtype=float)
        if x0.size == 0 or not np.isfinite(x0).all():
            raise ValueError(f"x0 must be a non-empty finite vector, got {x0!r}")
        if basis.ndim != 2 or basis.shape[0] != x0.size or basis.shape[1] < 1 or not np.isfinite(basis).all():
            raise ValueError(f"basis must be a finite ({x0.size}, k >= 1) array, got shape {basis.shape}")
        for name, v in (("sigma_subspace", sigma_subspace), ("sigma_full", sigma_full)):
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive finite step size, got {v!r}")
        if subspace_evaluations < 0:
            raise ValueError(f"subspace_evaluations must be >= 0, got {subspace_evaluations}")
        self.n_params = x0.size
        self.x0 = x0
        self.basis = basis
        self.bounds = None if bounds is None else CMAES._check_bounds(bounds, x0)
        self.sigma_subspace = float(sigma_subspace)
        self.sigma_full = float(sigma_full)
        self.subspace_evaluations = int(subspace_evaluations)
        self.popsize_subspace = popsize_subspace
        self.popsize = popsize
        self.cma_options = dict(cma_options or {})
        self.rng = rng
        self.stage = 1
        self.n_subspace_told = 0
        self._init_best(x0)
        self.subspace: CMAES | None = CMAES(np.zeros(basis.shape[1]), sigma_subspace, rng, popsize=popsize_subspace, cma_options=self.cma_options)
        self.full: CMAES | None = None
        if self.subspace_evaluations == 0:
            self._switch()

    def _embed(self, Z: np.ndarray) -> np.ndarray:
        X = self.x0 + np.atleast_2d(Z) @ self.basis.T
        return X if self.bounds is None else np.clip(X, self.bounds[:, 0], self.bounds[:, 1])

    def _switch(self) -> None:
        """Start stage 2 at the best candidate so far (kept strictly inside the bounds)."""
        x = self._best_params.copy()
        if self.bounds is not None:
            x = np.clip(x, self.bounds[:, 0] + 1e-9, self.bounds[:, 1] - 1e-9)
        rng = self.subspace.rng if self.subspace is not None else self.rng
        self.full = CMAES(x, self.sigma_full, rng, popsize=self.popsize, bounds=self.bounds, cma_options=self.cma_options)
        self.stage = 2
        self.subspace = None

    def ask(self) -> np.ndarray:
        if self.stage == 1:
            return self._embed(self.subspace.ask())
        return self.full.ask()

    def tell(self, candidates: np.ndarray, rewards: np.ndarray) -> None:
        candidates = np.asarray(candidates, dtype=float)
        rewards = np.asarray(rewards, dtype=float).ravel()
        if self.stage == 1:
            Z = self.subspace.ask()  # the pending batch (ask is idempotent until tell)
            if candidates.shape != (Z.shape[0], self.n_params) or not np.allclose(candidates, self._embed(Z)):
                raise ValueError("tell() needs the candidates returned by the last ask()")
            self._record_batch(candidates, rewards)
            self.subspace.tell(Z, rewards)
            self.n_subspace_told += rewards.size
            if self.n_subspace_told >= self.subspace_evaluations or self.subspace.stop():
                self._switch()
            return
        self._record_batch(candidates, rewards)
        self.full.tell(candidates, rewards)

    @property
    def mean(self) -> np.ndarray:
        """Mean of the current search distribution, in the full space."""
        return self._embed(self.subspace.mean)[0] if self.stage == 1 else self.full.mean

    def stop(self) -> bool:
        return self.stage == 2 and self.full.stop()

    def state_dict(self) -> dict[str, Any]:
        return {
            "type": "StagedCMAES",
            "config": {
                "x0": self.x0,
                "basis": self.basis,
                "sigma_subspace": self.sigma_subspace,
                "sigma_full": self.sigma_full,
                "subspace_evaluations": self.subspace_evaluations,
                "popsize_subspace": self.popsize_subspace,
                "popsize": self.popsize,
                "bounds": self.bounds,
                "cma_options": self.cma_options,
            },
            "stage": self.stage,
            "n_subspace_told": self.n_subspace_told,
            **self._best_state(),
            "subspace": None if self.subspace is None else self.subspace.state_dict(),
            "full": None if self.full is None else self.full.state_dict(),
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "StagedCMAES":
        if state.get("type") != "StagedCMAES":
            raise ValueError(f"not a StagedCMAES state (type={state.get('type')!r})")
        cfg = state["config"]
        inner = state["subspace"] if state["subspace"] is not None else state["full"]
        opt = cls(
            np.asarray(cfg["x0"]),
            np.asarray(cfg["basis"]),
            cfg["sigma_subspace"],
            cfg["sigma_full"],
            rng_from_state(inner["rng"]),
            subspace_evaluations=max(1, int(cfg["subspace_evaluations"])),
            popsize_subspace=cfg["popsize_subspace"],
            popsize=cfg["popsize"],
            bounds=None if cfg["bounds"] is None else np.asarray(cfg["bounds"]),
            cma_options=cfg["cma_options"],
        )
        opt.subspace_evaluations = int(cfg["subspace_evaluations"])
        opt.stage = int(state["stage"])
        opt.n_subspace_told = int(state["n_subspace_told"])
        opt._restore_best(state)
        if opt.stage == 1:
            opt.subspace = CMAES.from_state(state["subspace"])
            opt.rng = opt.subspace.rng
        else:
            opt.subspace = None
            opt.full = CMAES.from_state(state["full"])
            opt.rng = opt.full.rng
        return opt


class StagnationRestartCMAES(BestAndWorst, Optimizer):
    """CMA-ES that restarts when it stalls, from the next of several start points (a maximiser).

    Each *attempt* is a :class:`CMAES` (population ``popsize``, step ``sigma0``) started at
    ``starts[k % len(starts)]`` for the ``k``-th attempt, or, with ``restart_from_best``, at the best
    candidate so far (every attempt after the first). An attempt ends when the best reward it has seen
    has improved by less than ``tol`` over its last ``stagnation_generations`` generations (a plateau),
    after ``max_generations`` generations (``0``: no such cap), or when ``cma`` stops it. Meant for
    multi-modal landscapes where a run either finds the good basin early or creeps along a bad one
    (the throw: slow downward throws that the search keeps lengthening), so one budget is spent on
    several short attempts instead of one long one.

    Restart regimes (``regimes``):

    * ``"large"`` (default): every attempt has step ``sigma0``; ``popsize_growth`` > 1 makes it IPOP-like,
      attempt ``k`` has population ``round(popsize * popsize_growth**k)``.
    * ``"bipop"``: after the first attempt, a restart is *small* (step ``sigma0 * 10**(-small_decades * u)``,
      ``u ~ U(0, 1)``, population ``popsize``, always from the best candidate so far: a local search of
      the best basin) whenever the episodes spent in small attempts are fewer than ``small_share`` times
      those spent in large ones, else *large* (step ``sigma0``, population ``round(popsize * popsize_growth**j)`` for the
      ``j``-th large restart, start point as above). After Hansen (2009), "Benchmarking a BI-population
      CMA-ES on the BBOB-2009 function testbed", with the restarts triggered by stagnation.
    * ``"local"``: a restart is small (as above) unless the last ``patience`` small attempts in a row
      each failed to raise the best reward so far by ``tol``: then one large restart, after which
      restarts are small again. A local search of the best basin that escalates to a large step only
      when it is stuck (instead of BIPOP's fixed share of episodes).

    Scouting (``scouts`` > 1): the first ``scouts`` attempts are independent short CMA-ES runs (step ``sigma0``,
    each from ``starts[k % len(starts)]``, at most ``scout_generations`` generations each, one after the other);
    then the scout with the best reward goes on (its CMA-ES state, not a fresh one) as the first attempt proper,
    and the restarts above follow. Meant for landscapes where the basin a run ends up in is decided early.
    With ``scout_halving`` the scouts are raced by successive halving (Jamieson & Talwalkar 2016): every scout
    runs ``scout_generations`` generations (a *rung*), then the better half of those that did not stall
    (rounded up) runs another ``scout_generations`` generations each, its own CMA-ES going on, and so on until
    one is left; it goes on as the first attempt proper. Four scouts cost 6 rungs of generations instead of 4.

    Budget and stop belong to the caller (the loop): :meth:`stop` is never true. One Generator drives
    every attempt; :meth:`state_dict` saves the attempt counter and regime bookkeeping, the per-generation
    best of the current attempt and the inner CMA-ES, so a resumed run asks the same candidates as an
    uninterrupted one.
    """

    def __init__(
        self,
        starts: np.ndarray,
        sigma0: float,
        rng: np.random.Generator,
        *,
        popsize: int | None = None,
        bounds: np.ndarray | None = None,
        stagnation_generations: int = 20,
        tol: float = 0.01,
        max_generations: int = 0,
        restart_from_best: bool = False,
        cma_options: dict[str, Any] | None = None,
        popsize_growth: float = 1.0,
        regimes: str = "large",
        small_decades: float = 2.0,
        small_share: float = 1.0,
        patience: int = 2,
        scouts: int = 0,
        scout_generations: int = 10,
        scout_halving: bool = False,
    ) -> None:
        starts = np.atleast_2d(np.asarray(starts, dtype=float))
        if starts.size == 0 or not np.isfinite(starts).all():
            raise ValueError(f"starts must be a non-empty finite (k, n) array, got {starts!r}")
        if not (np.isfinite(sigma0) and sigma0 > 0):
            raise ValueError(f"sigma0 must be a positive finite step size, got {sigma0!r}")
        if stagnation_generations < 1 or max_generations < 0:
            raise ValueError(f"stagnation_generations must be >= 1 and max_generations >= 0, got {stagnation_generations}, {max_generations}")
        if not (np.isfinite(tol) and tol >= 0):
            raise ValueError(f"tol must be a finite number >= 0, got {tol!r}")
        if not (np.isfinite(popsize_growth) and popsize_growth >= 1):
            raise ValueError(f"popsize_growth must be a finite number >= 1, got {popsize_growth!r}")
        if regimes not in _STAGNATION_REGIMES:
            raise ValueError(f"regimes must be one of {_STAGNATION_REGIMES}, got {regimes!r}")
        if not (np.isfinite(small_decades) and small_decades >= 0):
            raise ValueError(f"small_decades must be a finite number >= 0, got {small_decades!r}")
        if not (np.isfinite(small_share) and small_share > 0):
            raise ValueError(f"small_share must be a finite number > 0, got {small_share!r}")
        if int(patience) != patience or patience < 1:
            raise ValueError(f"patience must be an integer >= 1, got {patience!r}")
        if int(scouts) != scouts or scouts < 0 or int(scout_generations) != scout_generations or scout_generations < 1:
            raise ValueError(f"scouts must be an integer >= 0 and scout_generations >= 1, got {scouts!r}, {scout_generations!r}")
        self.n_params = starts.shape[1]
        self.bounds = None if bounds is None else np.asarray(bounds, dtype=float)
        if self.bounds is not None:
            for s in starts:
                CMAES._check_bounds(self.bounds, s)
        self.starts = starts
        self.sigma0 = float(sigma0)
        self.rng = rng
        self.popsize = popsize
        self.stagnation_generations = int(stagnation_generations)
        self.tol = float(tol)
        self.max_generations = int(max_generations)
        self.restart_from_best = bool(restart_from_best)
        self.cma_options = dict(cma_options or {})
        self.popsize_growth = float(popsize_growth)
        self.regimes = regimes
        self.small_decades = float(small_decades)
        self.small_share = float(small_share)
        self.patience = int(patience)
        self.scouts = int(scouts)
        self.scout_generations = int(scout_generations)
        self.scout_halving = bool(scout_halving)
        #: successive halving (``scout_halving``): the rung, the scout now running, the scouts still to run in this rung
        #: (their CMA-ES and per-generation best; ``None``: a fresh scout from its start point) and those that finished it
        self.rung = 0
        self.current_scout = 0
        self.rung_queue: list[tuple[int, CMAES | None, list[float]]] = [(k, None, []) for k in range(1, self.scouts)] if self.scout_halving else []
        self.rung_done: list[tuple[int, CMAES, list[float]]] = []
        #: scouting: the best scout so far (its CMA-ES, and its per-generation best), kept to go on after the last scout
        self.kept: CMAES | None = None
        self.kept_best: list[float] = []
        #: the scout (attempt number) kept so far, and the one whose CMA-ES the current attempt continues (None: a fresh attempt)
        self.kept_scout: int | None = None
        self.continued_scout: int | None = None
        self.attempt = 0
        #: regime bookkeeping: regime of the current attempt, large restarts so far, episodes per regime
        self.regime = "large"
        self.n_large_restarts = 0
        self.evaluations = {"large": 0, "small": 0}
        #: "local" regimes: small attempts in a row that did not raise the best by ``tol``; best reward when the attempt began
        self.small_streak = 0
        self.attempt_start_best = -np.inf
        #: best reward of the current attempt after each of its generations
        self.attempt_best: list[float] = []
        #: one entry per finished attempt: start index (-1: best so far), generations, best reward, why it ended, regime, step, population
        self.attempt_history: list[dict[str, Any]] = []
        self._init_best(starts[0])
        self.inner = self._new_attempt(self.sigma0)

    def scouting(self) -> bool:
        """True while the current attempt is one of the scouts (see the class docstring)."""
        if self.scouts > 1 and self.scout_halving:
            return self.current_scout >= 0
        return self.scouts > 1 and self.attempt < self.scouts

    def _start_point(self) -> tuple[int, np.ndarray]:
        if (self.restart_from_best or self.regime == "small") and self.attempt > 0 and np.isfinite(self._best_reward) and not self.scouting():
            return -1, self._best_params.copy()
        i = self.attempt % len(self.starts)
        return i, self.starts[i].copy()

    def _new_attempt(self, sigma: float, x: np.ndarray | None = None) -> CMAES:
        """A fresh CMA-ES of step ``sigma`` from ``x`` (default: :meth:`_start_point`), clipped into the bounds."""
        if x is None:
            _, x = self._start_point()
        if self.bounds is not None:
            span = self.bounds[:, 1] - self.bounds[:, 0]
            x = np.clip(x, self.bounds[:, 0] + 1e-9 * span, self.bounds[:, 1] - 1e-9 * span)
        return CMAES(x, sigma, self.rng, popsize=self.attempt_popsize(), bounds=self.bounds, cma_options=self.cma_options)

    def attempt_popsize(self) -> int | None:
        """Population of the current attempt (``None``: ``cma``'s default, not grown)."""
        if self.popsize is None or self.popsize_growth == 1.0 or self.regime == "small":
            return self.popsize
        k = self.attempt if self.regimes == "large" else self.n_large_restarts
        return max(2, int(round(self.popsize * self.popsize_growth**k)))

    def _next_regime(self) -> float:
        """Choose the regime of the next attempt (sets :attr:`regime`); returns its step size."""
        if self.regimes == "local":
            improved = self._best_reward - self.attempt_start_best >= self.tol
            self.small_streak = 0 if (self.regime == "large" or improved) else self.small_streak + 1
            if self.small_streak < self.patience:
                self.regime = "small"
                return self.sigma0 * 10 ** (-self.small_decades * float(self.rng.uniform()))
            self.small_streak = 0
        elif self.regimes == "bipop" and self.evaluations["small"] < self.small_share * self.evaluations["large"]:
            self.regime = "small"
            return self.sigma0 * 10 ** (-self.small_decades * float(self.rng.uniform()))
        self.regime = "large"
        if self.attempt > 0:
            self.n_large_restarts += 1
        return self.sigma0

    def ask(self) -> np.ndarray:
        return self.inner.ask()

    def stalled(self) -> str | None:
        """Why the current attempt should end now (``None``: it goes on)."""
        g = len(self.attempt_best)
        if self.inner.stop():
            return "cma"
        if self.max_generations and g >= self.max_generations:
            return "max_generations"
        G = self.stagnation_generations
        if g > G and self.attempt_best[-1] - self.attempt_best[-1 - G] < self.tol:
            return "stagnation"
        if self.scouting() and g >= self.scout_generations * (self.rung + 1 if self.scout_halving else 1):
            return "scout"
        return None

    def tell(self, candidates: np.ndarray, rewards: np.ndarray) -> None:
        candidates = np.asarray(candidates, dtype=float)
        rewards = np.asarray(rewards, dtype=float).ravel()
        clean, failed = self._record_batch(candidates, rewards)
        self.inner.tell(candidates, rewards)
        self.evaluations[self.regime] += rewards.size
        prev = self.attempt_best[-1] if self.attempt_best else -np.inf
        ok = clean[~failed]
        self.attempt_best.append(max(prev, float(ok.max())) if ok.size else prev)
        why = self.stalled()
        if why is not None:
            halving = self.scout_halving and self.scouting()
            index, _ = self._start_point()
            if halving:
                index = self.current_scout % len(self.starts)
            if self.continued_scout is not None:
                index = self.continued_scout % len(self.starts)  # the scout's start point
            entry = {"start": index, "generations": len(self.attempt_best), "best_reward": float(self.attempt_best[-1]), "end": why}
            if halving:
                entry |= {"scout": self.current_scout, "rung": self.rung}
            if self.continued_scout is not None:
                entry["continues_scout"] = self.continued_scout
            if self.regimes != "large" or self.popsize_growth != 1.0:
                entry |= {"regime": self.regime, "sigma0": float(self.inner.sigma0), "popsize": int(self.inner.popsize0)}
            self.attempt_history.append(entry)
            if halving:
                self._next_scout(why)
                return
            if why == "scout" and (not self.kept_best or self.attempt_best[-1] > self.kept_best[-1]):
                self.kept, self.kept_best, self.kept_scout = self.inner, list(self.attempt_best), self.attempt
            self.attempt += 1
            self.attempt_best = []
            self.continued_scout = None
            if self.scouting():
                self.inner = self._new_attempt(self.sigma0)
            elif self.scouts > 1 and self.attempt == self.scouts and self.kept is not None:
                # scouting is over: the best scout goes on (a large attempt)
                self.inner, self.attempt_best, self.continued_scout = self.kept, self.kept_best, self.kept_scout
                self.kept, self.kept_best, self.kept_scout = None, [], None
            else:
                self.inner = self._new_attempt(self._next_regime())
            self.attempt_start_best = float(self._best_reward)

    def _next_scout(self, why: str) -> None:
        """Successive halving: file the scout that just ended (``why``) and switch to the next one, the next rung,
        or, with one scout left (or none that did not stall), to the first attempt proper."""
        if why == "scout":
            self.rung_done.append((self.current_scout, self.inner, list(self.attempt_best)))
        self.attempt += 1
        if not self.rung_queue and len(self.rung_done) > 1:
            ranked = sorted(self.rung_done, key=lambda e: -e[2][-1])  # stable: an earlier scout wins a tie
            self.rung_queue = [(k, cma, best) for k, cma, best in ranked[: (len(ranked) + 1) // 2]]
            self.rung_done = []
            self.rung += 1
            if len(self.rung_queue) == 1:  # the race is decided
                self.rung_done, self.rung_queue = self.rung_queue, []
        if self.rung_queue:
            k, cma, best = self.rung_queue.pop(0)
            self.current_scout, self.attempt_best = k, list(best)
            self.inner = cma if cma is not None else self._new_attempt(self.sigma0, self.starts[k % len(self.starts)].copy())
        else:  # scouting is over: the winner goes on as a large attempt (a fresh one if every scout stalled)
            self.current_scout = -1
            self.attempt_best = []
            if self.rung_done:
                k, cma, best = self.rung_done[0]
                self.inner, self.attempt_best, self.continued_scout = cma, list(best), k
                self.rung_done = []
            else:
                self.inner = self._new_attempt(self._next_regime())
        self.attempt_start_best = float(self._best_reward)

    @property
    def mean(self) -> np.ndarray:
        """Mean of the current attempt's search distribution."""
        return self.inner.mean

    def state_dict(self) -> dict[str, Any]:
        extra_cfg: dict[str, Any] = {}
        if self.popsize_growth != 1.0:
            extra_cfg["popsize_growth"] = self.popsize_growth
        if self.regimes != "large":
            extra_cfg |= {"regimes": self.regimes, "small_decades": self.small_decades}
            if self.small_share != 1.0:
                extra_cfg["small_share"] = self.small_share
            if self.regimes == "local":
                extra_cfg["patience"] = self.patience
        if self.scouts > 1:
            extra_cfg |= {"scouts": self.scouts, "scout_generations": self.scout_generations}
            if self.scout_halving:
                extra_cfg["scout_halving"] = True
        halving_state: dict[str, Any] = {}
        if self.scouts > 1 and self.scout_halving:
            halving_state = {"halving": {
                "rung": self.rung, "current_scout": self.current_scout,
                "queue": [{"scout": k, "cma": None if c is None else c.state_dict(), "best": [float(v) for v in b]} for k, c, b in self.rung_queue],
                "done": [{"scout": k, "cma": c.state_dict(), "best": [float(v) for v in b]} for k, c, b in self.rung_done]}}
        return {
            "type": "StagnationRestartCMAES",
            "config": {
                "starts": self.starts,
                "sigma0": self.sigma0,
                "popsize": self.popsize,
                "bounds": self.bounds,
                "stagnation_generations": self.stagnation_generations,
                "tol": self.tol,
                "max_generations": self.max_generations,
                "restart_from_best": self.restart_from_best,
                "cma_options": self.cma_options,
                **extra_cfg,
            },
            "attempt": self.attempt,
            "regime": {"regime": self.regime, "n_large_restarts": self.n_large_restarts, "evaluations": dict(self.evaluations),
                       **({"small_streak": self.small_streak, "attempt_start_best": float(self.attempt_start_best)} if self.regimes == "local" else {})},
            "attempt_best": [float(v) for v in self.attempt_best],
            "attempt_history": self.attempt_history,
            **self._best_state(),
            "inner": self.inner.state_dict(),
            **({"kept": None if self.kept is None else self.kept.state_dict(), "kept_best": [float(v) for v in self.kept_best],
                "kept_scout": self.kept_scout, "continued_scout": self.continued_scout} if self.scouts > 1 else {}),
            **halving_state,
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "StagnationRestartCMAES":
        if state.get("type") != "StagnationRestartCMAES":
            raise ValueError(f"not a StagnationRestartCMAES state (type={state.get('type')!r})")
        cfg = state["config"]
        inner = CMAES.from_state(state["inner"])
        opt = cls.__new__(cls)
        opt.n_params = inner.n_params
        opt.starts = np.atleast_2d(np.asarray(cfg["starts"], dtype=float))
        opt.sigma0 = float(cfg["sigma0"])
        opt.popsize = cfg["popsize"]
        opt.bounds = None if cfg["bounds"] is None else np.asarray(cfg["bounds"], dtype=float)
        opt.stagnation_generations = int(cfg["stagnation_generations"])
        opt.tol = float(cfg["tol"])
        opt.max_generations = int(cfg["max_generations"])
        opt.restart_from_best = bool(cfg["restart_from_best"])
        opt.cma_options = dict(cfg["cma_options"])
        opt.popsize_growth = float(cfg.get("popsize_growth", 1.0))
        opt.regimes = str(cfg.get("regimes", "large"))
        opt.small_decades = float(cfg.get("small_decades", 2.0))
        opt.small_share = float(cfg.get("small_share", 1.0))
        opt.patience = int(cfg.get("patience", 2))
        opt.scouts = int(cfg.get("scouts", 0))
        opt.scout_generations = int(cfg.get("scout_generations", 10))
        opt.scout_halving = bool(cfg.get("scout_halving", False))
        hv = state.get("halving", {})

        def _cma(d):
            if d is None:
                return None
            c = CMAES.from_state(d)
            c.rng = inner.rng  # one Generator drives every attempt
            return c

        opt.rung = int(hv.get("rung", 0))
        opt.current_scout = int(hv.get("current_scout", -1))
        opt.rung_queue = [(int(e["scout"]), _cma(e["cma"]), [float(v) for v in e["best"]]) for e in hv.get("queue", [])]
        opt.rung_done = [(int(e["scout"]), _cma(e["cma"]), [float(v) for v in e["best"]]) for e in hv.get("done", [])]
        opt.kept = None if state.get("kept") is None else CMAES.from_state(state["kept"])
        if opt.kept is not None:
            opt.kept.rng = inner.rng  # one Generator drives every attempt
        opt.kept_best = [float(v) for v in state.get("kept_best", [])]
        opt.kept_scout = None if state.get("kept_scout") is None else int(state["kept_scout"])
        opt.continued_scout = None if state.get("continued_scout") is None else int(state["continued_scout"])
        reg = state.get("regime", {})  # absent in states written before the regimes existed
        opt.regime = str(reg.get("regime", "large"))
        opt.n_large_restarts = int(reg.get("n_large_restarts", state["attempt"]))
        ev = reg.get("evaluations", {})
        opt.evaluations = {"large": int(ev.get("large", 0)), "small": int(ev.get("small", 0))}
        opt.small_streak = int(reg.get("small_streak", 0))
        opt.attempt_start_best = float(reg.get("attempt_start_best", -np.inf))
        opt.attempt = int(state["attempt"])
        opt.attempt_best = [float(v) for v in state["attempt_best"]]
        opt.attempt_history = [dict(e) for e in state["attempt_history"]]
        opt._restore_best(state)
        opt.inner = inner
        opt.rng = inner.rng
        return opt
