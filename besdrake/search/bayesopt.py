"""Bayesian optimization on a box with an ask/tell interface.

One GP (:class:`~besdrake.search.gp.GaussianProcess`) models the reward; each :meth:`ask` proposes
one candidate by maximising an acquisition function:

* ``"ucb"``: upper confidence bound ``mean + kappa * std``;
* ``"ei"``: expected improvement over the best posterior mean at the data;
* ``"es"``: entropy search (Hennig & Schuler 2012), Monte-Carlo version of
  :mod:`besdrake.search.entropy_search`;
* ``"mrs"``: minimum regret search (Metzen 2016), :mod:`besdrake.search.mrs`.

The first ``n_initial`` candidates are uniform random. ES and MRS are maximised over a finite
candidate set (the representer points, the best UCB points of a random pool and a few uniform
points), UCB and EI over a random pool refined by L-BFGS-B. :meth:`recommend` returns the
posterior-mean maximiser (the usual final answer of BO); :attr:`best` the best observed point.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .acquisition import expected_improvement, maximize_on_box, upper_confidence_bound
from .base import Optimizer
from .entropy_search import RepresenterModel, select_representers
from .gp import GaussianProcess, GPEpisodes, check_bounds, single_threaded

__all__ = ["BayesianOptimizer", "ACQUISITIONS"]

ACQUISITIONS = ("ucb", "ei", "es", "mrs")


class BayesianOptimizer(GPEpisodes, Optimizer):
    """GP-based maximiser of an expensive reward on a box.

    Parameters
    ----------
    bounds:
        Search box, shape ``(n_params, 2)``.
    acquisition:
        One of :data:`ACQUISITIONS`.
    rng:
        The only source of randomness (also seeds the GP hyperparameter restarts).
    n_initial:
        Uniform random evaluations before the model is used (default ``n_params + 3``).
    budget:
        Optional number of evaluations after which :meth:`stop` is true.
    kappa, xi:
        Exploration weights of UCB and EI.
    n_representers, n_samples, n_fantasies, pool_size:
        Monte-Carlo settings of ES / MRS and the size of the random pools.
    nu, n_restarts:
        GP kernel smoothness and hyperparameter restarts.
    """

    def __init__(
        self,
        bounds: Any,
        acquisition: str = "es",
        rng: np.random.Generator | None = None,
        n_initial: int | None = None,
        budget: int | None = None,
        kappa: float = 2.0,
        xi: float = 0.0,
        n_representers: int = 50,
        n_samples: int = 256,
        n_fantasies: int = 5,
        pool_size: int = 500,
        nu: float = 2.5,
        n_restarts: int = 1,
    ) -> None:
        self.bounds = check_bounds(bounds)
        self.n_params = self.bounds.shape[0]
        if acquisition not in ACQUISITIONS:
            raise ValueError(f"unknown acquisition {acquisition!r}; choose one of {ACQUISITIONS}")
        self.acquisition = acquisition
        self.rng = rng if rng is not None else np.random.default_rng()
        self.n_initial = int(n_initial) if n_initial is not None else self.n_params + 3
        if self.n_initial < 1:
            raise ValueError(f"n_initial must be >= 1, got {self.n_initial}")
        self.budget = budget
        self.kappa, self.xi = float(kappa), float(xi)
        self.n_representers, self.n_samples, self.n_fantasies = int(n_representers), int(n_samples), int(n_fantasies)
        self.pool_size = int(pool_size)
        self.gp = GaussianProcess(self.bounds, nu=nu, n_restarts=n_restarts, seed=int(self.rng.integers(2**31 - 1)))
        self._init_episodes(self.n_params)

    # ------------------------------------------------------------------ ask / tell
    @single_threaded
    def ask(self) -> np.ndarray:
        """The next candidate, shape ``(1, n_params)``."""
        low, high = self.bounds[:, 0], self.bounds[:, 1]
        if len(self.y) < self.n_initial:
            return self.rng.uniform(low, high)[None, :]
        self._fit()
        if self.acquisition == "ucb":
            x, _ = maximize_on_box(lambda X: upper_confidence_bound(self.gp, X, self.kappa), self.bounds, self.rng,
                                   self.pool_size, extra=self.X)
        elif self.acquisition == "ei":
            incumbent = float(self.gp.predict(self.X).max())
            x, _ = maximize_on_box(lambda X: expected_improvement(self.gp, X, incumbent, self.xi), self.bounds,
                                   self.rng, self.pool_size, extra=self.X)
        else:
            x = self._ask_information()
        return x[None, :]

    def _ask_information(self) -> np.ndarray:
        low, high = self.bounds[:, 0], self.bounds[:, 1]
        pool = np.vstack([self.rng.uniform(low, high, size=(self.pool_size, self.n_params)), self.X])
        incumbent = float(self.gp.predict(self.X).max())
        representers = select_representers(self.gp, pool, self.n_representers, self.rng, incumbent)
        model = RepresenterModel(self.gp, representers, self.rng, self.n_samples, self.n_fantasies)
        ucb = upper_confidence_bound(self.gp, pool, self.kappa)
        candidates = np.vstack([representers, pool[np.argsort(-ucb)[:20]],
                                self.rng.uniform(low, high, size=(20, self.n_params))])
        if self.acquisition == "es":
            values = model.information_gain(candidates)
        else:
            values = model.regret_reduction(candidates)
        return candidates[int(np.argmax(values))].copy()

    def tell(self, candidates: np.ndarray, rewards: np.ndarray) -> None:
        """Add evaluated candidates; NaN/inf rewards count as failed episodes (penalised)."""
        candidates = np.atleast_2d(np.asarray(candidates, dtype=float))
        rewards = np.atleast_1d(np.asarray(rewards, dtype=float))
        if candidates.shape != (rewards.size, self.n_params):
            raise ValueError(f"candidates must have shape ({rewards.size}, {self.n_params}), got {candidates.shape}")
        if not np.isfinite(candidates).all():
            raise ValueError("candidates contain NaN or inf")
        self._add_episodes(candidates, rewards)

    # ------------------------------------------------------------------ results
    @property
    def best(self) -> tuple[np.ndarray, float]:
        """Best successful evaluation and its reward; a failed episode is never the best.

        Before any successful evaluation: the centre of the box and ``-inf``.
        """
        ok = np.flatnonzero(~self.failed)
        if not ok.size:
            return self.bounds.mean(axis=1), -np.inf
        i = int(ok[np.argmax(self.y[ok])])
        return self.X[i].copy(), float(self.y[i])

    @single_threaded
    def recommend(self) -> np.ndarray:
        """Maximiser of the posterior mean (the recommendation after the search)."""
        if not self.y.size:
            return self.bounds.mean(axis=1)
        self._fit()
        x, _ = maximize_on_box(lambda X: self.gp.predict(X), self.bounds, None, extra=self.X, n_local=1)
        return x

    def stop(self) -> bool:
        return self.budget is not None and len(self.y) >= self.budget

    # ------------------------------------------------------------------ persistence
    def _settings(self) -> dict[str, Any]:
        return {
            "acquisition": self.acquisition, "n_initial": self.n_initial, "budget": self.budget,
            "kappa": self.kappa, "xi": self.xi, "n_representers": self.n_representers,
            "n_samples": self.n_samples, "n_fantasies": self.n_fantasies, "pool_size": self.pool_size,
            "nu": self.gp.nu, "n_restarts": self.gp.n_restarts,
        }

    def state_dict(self) -> dict[str, Any]:
        return {
            "type": type(self).__name__,
            "bounds": self.bounds.copy(),
            "settings": self._settings(),
            **self._episodes_state(),
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "BayesianOptimizer":
        opt = cls(state["bounds"], **state["settings"])
        opt._restore_episodes(state)
        return opt
