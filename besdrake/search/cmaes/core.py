"""CMA-ES through the ``cma`` package behind the ask/tell interface, with IPOP/BIPOP restarts (see the package
docstring of :mod:`besdrake.search.cmaes`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import cma
import numpy as np

from besdrake.search.base import BestAndWorst, Optimizer, rng_from_state, rng_state
from besdrake.search.cmaes.state import es_state, restore_es

_RESTART_STRATEGIES = ("none", "ipop", "bipop")



@dataclass
class _Run:
    """Bookkeeping of one (re)start."""

    popsize: int
    sigma0: float
    regime: str  # "large" or "small"


def _checked_fixed(fixed: Sequence[int], n: int) -> np.ndarray:
    """Sorted unique indices of fixed coordinates of an ``n``-vector, at least one left free; else ValueError."""
    idx = np.unique(np.asarray(list(fixed), dtype=int)) if len(fixed) else np.zeros(0, dtype=int)
    if idx.size and (idx[0] < 0 or idx[-1] >= n):
        raise ValueError(f"fixed coordinates must index the {n} parameters, got {list(fixed)!r}")
    if idx.size >= n:
        raise ValueError("at least one coordinate must be free")
    return idx


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
    fixed:
        Indices of coordinates held at ``x0``'s values: ``cma`` searches the others only (its dimension, population
        default and random draws are those of the free coordinates), and every candidate carries the fixed values
        (e.g. which imitated movement a candidate varies: :class:`~besdrake.search.refinement.RefinementProblem`).
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
        fixed: Sequence[int] = (),
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
        self.fixed = _checked_fixed(fixed, x0.size)
        self._free = np.setdiff1d(np.arange(x0.size), self.fixed)
        self.sigma0 = float(sigma0)
        self.rng = rng
        self.bounds = None if bounds is None else self._check_bounds(bounds, x0)
        self.restarts = int(restarts)
        self.restart_strategy = "none" if restarts == 0 else restart_strategy
        self.tolfun = float(tolfun)
        self.tolx = float(tolx)
        self.cma_options = dict(cma_options or {})
        self.popsize0 = int(popsize) if popsize is not None else 4 + int(3 * math.log(self._free.size))
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
            options["bounds"] = [list(self.bounds[self._free, 0]), list(self.bounds[self._free, 1])]
        options.update(self.cma_options)
        stds = options.get("CMA_stds")
        if stds is not None and np.size(stds) == self.n_params:  # given for every coordinate: the free ones'
            options["CMA_stds"] = list(np.asarray(stds, dtype=float)[self._free])
        return cma.CMAEvolutionStrategy(self.x0[self._free].copy(), run.sigma0, options)

    def _full(self, free: np.ndarray) -> np.ndarray:
        """Candidates of the free coordinates (rows) with the fixed coordinates at ``x0``'s values."""
        free = np.atleast_2d(np.asarray(free, dtype=float))
        out = np.repeat(self.x0[None, :], free.shape[0], axis=0)
        out[:, self._free] = free
        return out

    # -- ask / tell ------------------------------------------------------------------------------
    def ask(self) -> np.ndarray:
        if self._pending is not None:
            return self._pending.copy()
        self._rng_before_ask = rng_state(self.rng)
        self._pending = self._full(np.array(self.es.ask(), dtype=float))
        return self._pending.copy()

    def tell(self, candidates: np.ndarray, rewards: np.ndarray) -> None:
        candidates = np.asarray(candidates, dtype=float)
        if self._pending is None or candidates.shape != self._pending.shape:
            raise ValueError("tell() needs the candidates returned by the last ask()")
        rewards, _ = self._record_batch(candidates, rewards)
        self.es.tell(list(candidates[:, self._free]), list(-rewards))
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
        return self._full(np.array(self.es.mean, dtype=float))[0]

    def stop(self) -> bool:
        return self._finished

    # -- persistence -----------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """State after the last :meth:`tell`; candidates asked but not told are asked again."""
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
                "fixed": [int(i) for i in self.fixed],
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
            **es_state(self.es),
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
            fixed=cfg.get("fixed", ()),
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
        restore_es(opt.es, state)
        opt._restore_best(state)
        return opt
