"""Closed-form acquisition functions (for maximisation) and a box optimiser for them.

The information-theoretic acquisitions (entropy search, minimum regret search) live in
:mod:`besdrake.search.entropy_search` and :mod:`besdrake.search.mrs`.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.optimize import minimize
from scipy.stats import norm

from .gp import GaussianProcess

__all__ = ["upper_confidence_bound", "expected_improvement", "maximize_on_box"]


def upper_confidence_bound(gp: GaussianProcess, X: np.ndarray, kappa: float = 2.0) -> np.ndarray:
    """UCB ``mean + kappa * std`` of the latent reward at ``X``."""
    mean, std = gp.predict(X, return_std=True)
    return mean + kappa * std


def expected_improvement(gp: GaussianProcess, X: np.ndarray, incumbent: float, xi: float = 0.0) -> np.ndarray:
    """Expected improvement over ``incumbent`` (a reward to beat), with exploration margin ``xi``."""
    mean, std = gp.predict(X, return_std=True)
    improvement = mean - incumbent - xi
    z = improvement / std
    return improvement * norm.cdf(z) + std * norm.pdf(z)


def maximize_on_box(
    fun: Callable[[np.ndarray], np.ndarray],
    bounds: np.ndarray,
    rng: np.random.Generator | None,
    n_random: int = 500,
    n_local: int = 2,
    extra: np.ndarray | None = None,
) -> tuple[np.ndarray, float]:
    """Maximise a vectorised function ``fun(X) -> (n,)`` on a box.

    Evaluates ``n_random`` uniform points (none when ``rng`` is None) plus the ``extra`` points,
    then refines the best ``n_local`` with L-BFGS-B (finite-difference gradients).
    Returns ``(x, fun(x))``.
    """
    low, high = bounds[:, 0], bounds[:, 1]
    parts = [] if rng is None else [rng.uniform(low, high, size=(n_random, bounds.shape[0]))]
    if extra is not None and len(extra):
        parts.append(np.clip(np.atleast_2d(extra), low, high))
    if not parts:
        raise ValueError("maximize_on_box needs random points (rng) or extra points")
    X = np.vstack(parts)
    values = fun(X)
    order = np.argsort(-values)
    best_x, best_v = X[order[0]].copy(), float(values[order[0]])
    scale = high - low
    for i in order[:n_local]:
        result = minimize(
            lambda u: -float(fun((low + u * scale)[None, :])[0]),
            (X[i] - low) / scale,
            method="L-BFGS-B",
            bounds=[(0.0, 1.0)] * bounds.shape[0],
            options={"maxiter": 50},
        )
        if np.isfinite(result.fun) and -result.fun > best_v:
            best_x, best_v = np.clip(low + result.x * scale, low, high), float(-result.fun)
    return best_x, best_v
