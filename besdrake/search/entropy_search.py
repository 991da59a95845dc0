"""Entropy search (Hennig & Schuler 2012) by Monte Carlo over representer points.

The quantity of interest is ``p_max``: the distribution of the location of the maximum of the
reward. Approximations (all standard in Monte-Carlo entropy search, documented here because they
determine what the numbers mean):

1. **Representer points.** ``p_max`` is a discrete distribution over a finite set of representer
   points. They are drawn from a random pool with probability proportional to expected improvement
   (Hennig & Schuler draw them from EI-like measures as well); the entropy is that of this discrete
   distribution, without the correction for the non-uniform base measure.
2. **Monte Carlo p_max.** ``p_max`` is the frequency with which each representer is the maximum of a
   joint posterior sample (``n_samples`` samples, common random numbers for all candidates so that
   candidates are compared under the same noise).
3. **Fantasies.** The expected entropy after observing ``y`` at a candidate ``x`` is averaged over
   ``n_fantasies`` Gauss-Hermite nodes of the predictive distribution of ``y``. The GP update is
   exact: the updated joint samples are obtained pathwise (Matheron's rule) from the current ones,
   ``f' = f + Sigma_Rx / v * (y - y_sample)``, where ``y_sample`` is drawn jointly with ``f``. So
   one candidate costs ``O(n_representers * n_samples * n_fantasies)`` and needs no new Cholesky.
   Hyperparameters are kept fixed during fantasising.
4. **Groups.** Representers may be split into groups of equal size (contextual entropy search: one
   group per representative context, Metzen 2015); ``p_max`` is then one distribution per group
   (the maximiser over parameters for that context) and the information gain is summed over groups.

The same machinery provides the expected regret used by minimum regret search
(:mod:`besdrake.search.mrs`).
"""

from __future__ import annotations

import numpy as np
from numpy.polynomial.hermite_e import hermegauss
from scipy.linalg import cholesky, solve_triangular

from .acquisition import expected_improvement
from .gp import GaussianProcess

__all__ = ["RepresenterModel", "select_representers", "entropy_search", "discrete_entropy"]

_CHUNK_FLOATS = 2_000_000


def discrete_entropy(p: np.ndarray, axis: int = -1) -> np.ndarray:
    """Entropy (nats) of discrete distributions along ``axis``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(p > 0, -p * np.log(p), 0.0)
    return terms.sum(axis=axis)


def select_representers(
    gp: GaussianProcess, pool: np.ndarray, n: int, rng: np.random.Generator, incumbent: float | None = None
) -> np.ndarray:
    """Draw ``n`` representer points from ``pool`` with probability proportional to EI.

    The posterior-mean maximiser of the pool is always included.
    """
    pool = np.atleast_2d(pool)
    n = min(n, len(pool))
    mean = gp.predict(pool)
    if incumbent is None:
        incumbent = float(mean.max())
    ei = expected_improvement(gp, pool, incumbent)
    weights = np.clip(ei, 0.0, None) + 1e-3 * max(float(ei.max()), 1e-12)
    best = int(np.argmax(mean))
    weights[best] = 0.0
    chosen = rng.choice(len(pool), size=n - 1, replace=False, p=weights / weights.sum()) if n > 1 else np.zeros(0, int)
    return pool[np.concatenate([[best], chosen]).astype(int)]


class RepresenterModel:
    """Joint posterior samples over representer points and their pathwise fantasy updates.

    Parameters
    ----------
    gp:
        Fitted model.
    representers:
        Array ``(n_groups, n_per_group, n_dims)`` (or ``(n, n_dims)`` for one group).
    n_samples, n_fantasies:
        Monte-Carlo samples of the joint posterior, Gauss-Hermite nodes over the fantasy outcome.
    """

    def __init__(
        self,
        gp: GaussianProcess,
        representers: np.ndarray,
        rng: np.random.Generator,
        n_samples: int = 256,
        n_fantasies: int = 5,
    ) -> None:
        representers = np.asarray(representers, dtype=float)
        if representers.ndim == 2:
            representers = representers[None]
        self.gp = gp
        self.n_groups, self.n_per_group, _ = representers.shape
        self.points = representers.reshape(-1, representers.shape[-1])
        self.mean, cov = gp.posterior(self.points)
        self.chol = _robust_cholesky(cov)
        n_rep = len(self.points)
        self.Z = rng.standard_normal((n_rep, n_samples))
        self.w = rng.standard_normal(n_samples)
        # (S, R): samples first, so that the maxima over representers are reductions along the
        # contiguous last axis; float32 halves the memory traffic of the fantasies (the dominant cost)
        self.LZ_T = np.ascontiguousarray((self.chol @ self.Z).T)
        self._LZ_T32 = self.LZ_T.astype(np.float32)
        nodes, weights = hermegauss(n_fantasies)
        self.nodes, self.weights = nodes, weights / weights.sum()

    # ------------------------------------------------------------------ current state
    def current_samples(self) -> np.ndarray:
        """Joint posterior samples ``(n_samples, n_groups, n_per_group)``."""
        f = self.mean[None, :] + self.LZ_T
        return f.reshape(-1, self.n_groups, self.n_per_group)

    def p_max(self) -> np.ndarray:
        """Current ``p_max`` per group, shape ``(n_groups, n_per_group)``."""
        return self._p_max(self.current_samples())

    def _p_max(self, f: np.ndarray) -> np.ndarray:
        # f: (..., n_samples, n_groups, n_per_group) -> frequencies (..., n_groups, n_per_group)
        idx = np.moveaxis(np.argmax(f, axis=-1), -2, -1)  # (..., G, S)
        lead = idx.shape[:-1]
        flat = idx.reshape(-1, idx.shape[-1])
        offsets = (np.arange(flat.shape[0]) * self.n_per_group)[:, None]
        counts = np.bincount((flat + offsets).ravel(), minlength=flat.shape[0] * self.n_per_group)
        return counts.reshape(*lead, self.n_per_group) / idx.shape[-1]

    # ------------------------------------------------------------------ fantasies
    def fantasies(self, candidates: np.ndarray):
        """Yield ``(slice, f, m)`` per chunk of candidates.

        ``f``: fantasised joint samples ``(c, n_fantasies, n_samples, n_groups, n_per_group)``, float32;
        ``m``: fantasised posterior means ``(c, n_fantasies, n_groups, n_per_group)``.
        """
        candidates = np.atleast_2d(np.asarray(candidates, dtype=float))
        n_rep = len(self.points)
        _, cov = self.gp.posterior(np.vstack([self.points, candidates]))
        cross = cov[:n_rep, n_rep:]  # (R, C)
        var_y = np.clip(np.diag(cov)[n_rep:], 0.0, None) + self.gp.noise_variance  # (C,)
        var_y = np.maximum(var_y, 1e-12 * max(1.0, float(np.mean(np.diag(cov)))))
        B = solve_triangular(self.chol, cross, lower=True, check_finite=False)  # (R, C)
        resid_sd = np.sqrt(np.clip(var_y - np.einsum("rc,rc->c", B, B), 0.0, None))
        n_samples = self.Z.shape[1]
        chunk = max(1, _CHUNK_FLOATS // (n_rep * n_samples * len(self.nodes)))
        shape = (self.n_groups, self.n_per_group)
        for start in range(0, len(candidates), chunk):
            sl = slice(start, min(start + chunk, len(candidates)))
            y_dev = B[:, sl].T @ self.Z + resid_sd[sl, None] * self.w[None, :]  # (c, S) centred sample of y
            gain = (cross[:, sl] / var_y[sl]).T  # (c, R)
            shift = (cross[:, sl] / np.sqrt(var_y[sl])).T  # (c, R): mean change per unit node
            resid = self._LZ_T32[None] - (y_dev[:, :, None] * gain[:, None, :]).astype(np.float32)  # (c, S, R)
            m = self.mean[None, None, :] + self.nodes[None, :, None] * shift[:, None, :]  # (c, Q, R)
            f = m.astype(np.float32)[:, :, None, :] + resid[:, None]  # (c, Q, S, R)
            c = f.shape[0]
            yield sl, f.reshape(c, len(self.nodes), n_samples, *shape), m.reshape(c, len(self.nodes), *shape)

    def entropy(self) -> float:
        """Current entropy of ``p_max``, summed over groups."""
        return float(discrete_entropy(self.p_max()).sum())

    def information_gain(self, candidates: np.ndarray) -> np.ndarray:
        """Expected reduction of the ``p_max`` entropy (summed over groups) per candidate."""
        h0 = self.entropy()
        gains = np.empty(len(np.atleast_2d(candidates)))
        for sl, f, _ in self.fantasies(candidates):
            h = discrete_entropy(self._p_max(f)).sum(axis=-1)  # (c, Q)
            gains[sl] = h0 - h @ self.weights
        return gains

    def expected_regret(self) -> float:
        """Expected simple regret of recommending the posterior-mean maximiser (summed over groups)."""
        f = self.current_samples()  # (S, G, R)
        m = self.mean.reshape(self.n_groups, self.n_per_group)
        return float((f.max(axis=-1).mean(axis=0) - m.max(axis=-1)).sum())

    def regret_reduction(self, candidates: np.ndarray) -> np.ndarray:
        """Expected reduction of the expected regret (summed over groups) per candidate."""
        r0 = self.expected_regret()
        out = np.empty(len(np.atleast_2d(candidates)))
        for sl, f, m in self.fantasies(candidates):
            regret = f.max(axis=-1).mean(axis=-2) - m.max(axis=-1)  # (c, Q, G)
            out[sl] = r0 - regret.sum(axis=-1) @ self.weights
        return out


def entropy_search(
    gp: GaussianProcess,
    representers: np.ndarray,
    candidates: np.ndarray,
    rng: np.random.Generator,
    n_samples: int = 256,
    n_fantasies: int = 5,
) -> np.ndarray:
    """Entropy-search acquisition (expected information gain about the maximiser) at ``candidates``."""
    return RepresenterModel(gp, representers, rng, n_samples, n_fantasies).information_gain(candidates)


def _robust_cholesky(cov: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor with the smallest diagonal jitter (relative to the mean variance) that works."""
    scale = max(float(np.mean(np.diag(cov))), 1e-300)
    jitter = 1e-10 * scale
    for _ in range(12):
        try:
            return cholesky(cov + jitter * np.eye(len(cov)), lower=True, check_finite=False)
        except np.linalg.LinAlgError:
            jitter *= 10.0
    raise ValueError("posterior covariance of the representer points is not positive definite (non-finite GP?)")
