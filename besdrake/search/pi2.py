"""Episodic Policy Improvement with Path Integrals (PI2; Theodorou, Buchli & Schaal 2010).

Black-box episodic form ("PI-BB", Stulp & Sigaud 2012): each episode's cost ``S = -R`` is mapped to
a probability by exponentiating the range-normalised cost,

    P_k = exp(-h (S_k - min S) / (max S - min S)) / sum_j exp(...),

and the new mean is the probability-weighted average of the sampled parameters. With
``covariance_update=True`` (PI2-CMA) the covariance becomes the probability-weighted covariance of
the samples around the *previous* mean, so the exploration grows along successful steps and shrinks
near the optimum (mixed into the old covariance with ``covariance_learning_rate``, see
:class:`~besdrake.search.reps.GaussianSearch`); otherwise it is kept (optionally multiplied by ``covariance_decay`` per update).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from besdrake.search.reps import GaussianSearch, weighted_gaussian_fit


def pi2_weights(rewards: np.ndarray, h: float) -> np.ndarray:
    """Path-integral probabilities of episodes with ``rewards`` (sum to one)."""
    costs = -np.asarray(rewards, dtype=float)
    spread = costs.max() - costs.min()
    if spread == 0.0:
        return np.full(costs.size, 1.0 / costs.size)
    p = np.exp(-h * (costs - costs.min()) / spread)
    return p / p.sum()


class PI2(GaussianSearch):
    """Episodic PI2 (PI-BB / PI2-CMA) maximiser (see module docstring).

    Parameters beyond :class:`~besdrake.search.reps.GaussianSearch`:

    h:
        Eliteness of the exponentiated costs (Theodorou et al. use 10).
    covariance_update:
        Adapt the covariance from the weighted samples (PI2-CMA); otherwise keep it fixed.
    covariance_decay:
        Factor in (0, 1] applied to a fixed covariance after each update (1: no decay).
    """

    def __init__(
        self,
        mean: np.ndarray,
        cov: float | np.ndarray,
        rng: np.random.Generator,
        *,
        h: float = 10.0,
        covariance_update: bool = True,
        covariance_decay: float = 1.0,
        n_samples_per_update: int | None = None,
        covariance_learning_rate: float = 0.2,
        min_variance: float = 0.0,
        tol_std: float = 1e-12,
        bounds: np.ndarray | None = None,
    ) -> None:
        if not (np.isfinite(h) and h > 0):
            raise ValueError(f"h must be positive, got {h!r}")
        if not 0 < covariance_decay <= 1:
            raise ValueError(f"covariance_decay must be in (0, 1], got {covariance_decay!r}")
        self.h = float(h)
        self.covariance_update = bool(covariance_update)
        self.covariance_decay = float(covariance_decay)
        super().__init__(
            mean,
            cov,
            rng,
            n_samples_per_update=n_samples_per_update,
            covariance_learning_rate=covariance_learning_rate,
            min_variance=min_variance,
            tol_std=tol_std,
            bounds=bounds,
        )

    def _config(self) -> dict[str, Any]:
        return {
            **super()._config(),
            "h": self.h,
            "covariance_update": self.covariance_update,
            "covariance_decay": self.covariance_decay,
        }

    def _update(self, samples: np.ndarray, rewards: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        weights = pi2_weights(rewards, self.h)
        mean, cov = weighted_gaussian_fit(samples, weights, center=self.mean)
        if not self.covariance_update:
            return mean, self.cov * self.covariance_decay
        return mean, self._blend(cov)
