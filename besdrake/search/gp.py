"""Gaussian-process surrogate for Bayesian optimization (a thin layer over scikit-learn).

:class:`GaussianProcess` wraps :class:`sklearn.gaussian_process.GaussianProcessRegressor` with the
conventions every Bayesian optimizer of :mod:`besdrake.search` relies on:

* inputs are normalised to the unit box given by ``bounds`` (so one set of length-scale bounds
  fits every problem), outputs are standardised (zero mean, unit variance);
* kernel ``C * Matern(nu, ARD length scales) + White``; hyperparameters by maximising the marginal
  likelihood (few restarts, warm-started from the previous fit);
* :meth:`predict` and :meth:`posterior` describe the **latent** function (without observation
  noise) in the original units, which is what acquisition functions need;
* :meth:`state_dict` / :meth:`from_state` store the data and the kernel hyperparameters so that a
  restored model predicts exactly like the saved one without re-optimising.
"""

from __future__ import annotations

import functools
import warnings
from typing import Any, Callable, TypeVar

import numpy as np
from scipy.linalg import solve_triangular
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import ConstantKernel, Kernel, Matern, WhiteKernel

from .base import rng_from_state, rng_state, sanitize_rewards

__all__ = ["GaussianProcess", "GPEpisodes", "check_bounds", "single_threaded", "DEFAULT_LENGTH_SCALE_BOUNDS"]

#: Length scales (on the unit box) the marginal likelihood may choose from, unless a caller narrows them.
DEFAULT_LENGTH_SCALE_BOUNDS = (1e-2, 1e1)

_F = TypeVar("_F", bound=Callable[..., Any])
_THREADPOOLS: Any = None


def single_threaded(method: _F) -> _F:
    """Run ``method`` with single-threaded BLAS.

    The matrices of Bayesian optimization are small (hundreds of rows); multi-threaded BLAS only adds
    synchronisation overhead there and, on a busy machine, made the search several times slower.
    """

    @functools.wraps(method)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        global _THREADPOOLS
        if _THREADPOOLS is None:
            from threadpoolctl import ThreadpoolController  # a dependency of scikit-learn

            _THREADPOOLS = ThreadpoolController()
        with _THREADPOOLS.limit(limits=1, user_api="blas"):
            return method(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


def check_bounds(bounds: Any, name: str = "bounds") -> np.ndarray:
    """Validate a box ``(n_dims, 2)`` with finite, strictly increasing limits."""
    bounds = np.asarray(bounds, dtype=float)
    if bounds.ndim != 2 or bounds.shape[1] != 2 or bounds.shape[0] == 0:
        raise ValueError(f"{name} must have shape (n_dims, 2), got {bounds.shape}")
    if not np.isfinite(bounds).all():
        raise ValueError(f"{name} must be finite, got {bounds.tolist()}")
    if not (bounds[:, 1] > bounds[:, 0]).all():
        raise ValueError(f"{name}: every upper limit must exceed its lower limit, got {bounds.tolist()}")
    return bounds


class GaussianProcess:
    """GP regression on a box with ARD Matern kernel, white noise and standardised outputs.

    Parameters
    ----------
    bounds:
        Box of the inputs, shape ``(n_dims, 2)``; inputs are mapped to ``[0, 1]^n_dims``.
    nu:
        Smoothness of the Matern kernel (0.5, 1.5, 2.5 or ``inf`` for RBF).
    n_restarts:
        Random restarts of the marginal-likelihood optimisation (the first start is the previous
        fit, so 0 already warm-starts).
    noise_bounds:
        Bounds of the white-noise variance in standardised output units.
    seed:
        Seeds the restarts; the fit on ``n`` points uses ``seed + n``, so fitting is deterministic
        and consumes no optimizer randomness.
    """

    def __init__(
        self,
        bounds: Any,
        nu: float = 2.5,
        n_restarts: int = 1,
        noise_bounds: tuple[float, float] = (1e-6, 1e-1),
        length_scale_bounds: tuple[float, float] = DEFAULT_LENGTH_SCALE_BOUNDS,
        seed: int = 0,
    ) -> None:
        self.bounds = check_bounds(bounds)
        self.n_dims = self.bounds.shape[0]
        self.nu = float(nu)
        self.n_restarts = int(n_restarts)
        self.noise_bounds = tuple(float(v) for v in noise_bounds)
        self.length_scale_bounds = tuple(float(v) for v in length_scale_bounds)
        self.seed = int(seed)
        self.kernel: Kernel = self._default_kernel()
        self.regressor_: GaussianProcessRegressor | None = None
        self.X_ = np.zeros((0, self.n_dims))
        self.y_ = np.zeros(0)
        self.y_mean_ = 0.0
        self.y_scale_ = 1.0

    # ------------------------------------------------------------------ fitting
    def _default_kernel(self) -> Kernel:
        return ConstantKernel(1.0, (1e-2, 1e2)) * Matern(
            length_scale=np.full(self.n_dims, 0.3), length_scale_bounds=self.length_scale_bounds, nu=self.nu
        ) + WhiteKernel(1e-3, self.noise_bounds)

    def normalize(self, X: np.ndarray) -> np.ndarray:
        """Map inputs from ``bounds`` to the unit box."""
        return (np.atleast_2d(X) - self.bounds[:, 0]) / (self.bounds[:, 1] - self.bounds[:, 0])

    def fit(self, X: np.ndarray, y: np.ndarray, optimize: bool = True) -> "GaussianProcess":
        """Fit to inputs ``X`` (n, n_dims) and finite targets ``y`` (n,).

        With ``optimize=False`` the current kernel hyperparameters are kept.
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        y = np.asarray(y, dtype=float).ravel()
        if X.shape != (y.size, self.n_dims):
            raise ValueError(f"X must have shape ({y.size}, {self.n_dims}), got {X.shape}")
        if y.size == 0:
            raise ValueError("cannot fit a Gaussian process without data")
        if not (np.isfinite(X).all() and np.isfinite(y).all()):
            raise ValueError("X and y must be finite (sanitize failed episodes before fitting)")
        self.X_, self.y_ = X.copy(), y.copy()
        self.y_mean_ = float(y.mean())
        scale = float(y.std())
        self.y_scale_ = scale if scale > 1e-12 * max(1.0, abs(self.y_mean_)) else 1.0
        yn = (y - self.y_mean_) / self.y_scale_
        regressor = GaussianProcessRegressor(
            kernel=self.kernel,
            alpha=1e-10,
            optimizer="fmin_l_bfgs_b" if optimize else None,
            n_restarts_optimizer=self.n_restarts if optimize else 0,
            normalize_y=False,
            random_state=(self.seed + y.size) % (2**31 - 1),
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            regressor.fit(self.normalize(X), yn)
        self.regressor_ = regressor
        self.kernel = regressor.kernel_
        return self

    # ------------------------------------------------------------------ prediction
    def _check_fitted(self) -> GaussianProcessRegressor:
        if self.regressor_ is None:
            raise RuntimeError("GaussianProcess is not fitted yet; call fit() first")
        return self.regressor_

    @property
    def noise_variance(self) -> float:
        """Observation-noise variance in original output units."""
        return float(self.kernel.k2.noise_level) * self.y_scale_**2

    @property
    def length_scales(self) -> np.ndarray:
        """ARD length scales in the unit box."""
        return np.atleast_1d(self.kernel.k1.k2.length_scale).astype(float)

    def _latent_cross(self, Xn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        reg = self._check_fitted()
        K_trans = reg.kernel_.k1(Xn, reg.X_train_)
        V = solve_triangular(reg.L_, K_trans.T, lower=True, check_finite=False)
        return K_trans, V

    def predict(self, X: np.ndarray, return_std: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Posterior mean (and standard deviation) of the latent function at ``X``."""
        reg = self._check_fitted()
        Xn = self.normalize(np.asarray(X, dtype=float))
        K_trans, V = self._latent_cross(Xn)
        mean = K_trans @ reg.alpha_ * self.y_scale_ + self.y_mean_
        if not return_std:
            return mean
        var = reg.kernel_.k1.diag(Xn) - np.einsum("ij,ij->j", V, V)
        return mean, np.sqrt(np.clip(var, 1e-16, None)) * self.y_scale_

    def posterior(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Joint posterior mean ``(n,)`` and covariance ``(n, n)`` of the latent function."""
        reg = self._check_fitted()
        Xn = self.normalize(np.asarray(X, dtype=float))
        K_trans, V = self._latent_cross(Xn)
        mean = K_trans @ reg.alpha_ * self.y_scale_ + self.y_mean_
        cov = (reg.kernel_.k1(Xn) - V.T @ V) * self.y_scale_**2
        return mean, 0.5 * (cov + cov.T)

    # ------------------------------------------------------------------ persistence
    def state_dict(self) -> dict[str, Any]:
        """Data, kernel hyperparameters (log-space ``theta``) and settings."""
        return {
            "bounds": self.bounds.copy(),
            "nu": self.nu,
            "n_restarts": self.n_restarts,
            "seed": self.seed,
            "noise_bounds": list(self.noise_bounds),
            "length_scale_bounds": list(self.length_scale_bounds),
            "theta": np.asarray(self.kernel.theta, dtype=float),
            "X": self.X_.copy(),
            "y": self.y_.copy(),
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "GaussianProcess":
        """Rebuild a model; refits on the stored data with the stored hyperparameters."""
        gp = cls(
            state["bounds"],
            nu=state["nu"],
            n_restarts=state["n_restarts"],
            noise_bounds=tuple(state["noise_bounds"]),
            length_scale_bounds=tuple(state["length_scale_bounds"]),
            seed=state["seed"],
        )
        theta = np.asarray(state["theta"], dtype=float)
        if theta.shape != gp.kernel.theta.shape or not np.isfinite(theta).all():
            raise ValueError(f"stored kernel hyperparameters are invalid: {theta.tolist()}")
        gp.kernel = gp.kernel.clone_with_theta(theta)
        X, y = np.asarray(state["X"], dtype=float), np.asarray(state["y"], dtype=float)
        if y.size:
            gp.fit(X.reshape(y.size, gp.n_dims), y, optimize=False)
        return gp


class GPEpisodes:
    """The evaluated episodes of a GP-based optimizer and its lazily refitted model (mixin).

    Shared by :class:`~besdrake.search.bayesopt.BayesianOptimizer` and
    :class:`~besdrake.search.bocps.BOCPS`: GP inputs ``X`` (one row per episode), rewards ``y``
    (failed episodes penalised by :func:`~besdrake.search.base.sanitize_rewards`), the mask
    ``failed``, the model ``gp`` (refitted only when asked after new data) and their persistence.
    """

    gp: GaussianProcess
    rng: np.random.Generator

    def _init_episodes(self, n_dims: int) -> None:
        self.X = np.zeros((0, n_dims))
        self.y = np.zeros(0)
        self.failed = np.zeros(0, dtype=bool)
        self._fitted = False

    def _add_episodes(self, X: np.ndarray, rewards: np.ndarray) -> None:
        """Append GP inputs ``X`` and their rewards; NaN/inf rewards count as failed (penalised)."""
        clean, failed = sanitize_rewards(rewards, float(self.y.min()) if self.y.size else None)
        self.X = np.vstack([self.X, X])
        self.y = np.concatenate([self.y, clean])
        self.failed = np.concatenate([self.failed, failed])
        self._fitted = False

    def _fit(self) -> None:
        if not self._fitted:
            self.gp.fit(self.X, self.y)
            self._fitted = True

    def _episodes_state(self) -> dict[str, Any]:
        return {
            "X": self.X.copy(),
            "y": self.y.copy(),
            "failed": self.failed.astype(np.int8),
            "fitted": self._fitted,
            "gp": self.gp.state_dict(),
            "rng": rng_state(self.rng),
        }

    def _restore_episodes(self, state: dict[str, Any]) -> None:
        """Inverse of :meth:`_episodes_state`; call after construction, which draws from ``rng``."""
        self.rng = rng_from_state(state["rng"])
        self.X = np.asarray(state["X"], dtype=float).reshape(-1, self.X.shape[1])
        self.y = np.asarray(state["y"], dtype=float).ravel()
        if not (np.isfinite(self.X).all() and np.isfinite(self.y).all()) or len(self.X) != len(self.y):
            raise ValueError(f"stored {type(self).__name__} data is corrupt: X and y must be finite and of equal length")
        self.failed = np.asarray(state["failed"]).astype(bool).ravel()
        self.gp = GaussianProcess.from_state(state["gp"])
        self._fitted = bool(state["fitted"]) and self.gp.y_.size == self.y.size
