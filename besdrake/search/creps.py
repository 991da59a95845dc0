"""Contextual REPS (C-REPS; Kupcsik et al. 2013) and bandit-based active context selection.

Upper-level policy: linear-Gaussian in context features,
``theta ~ N(W^T phi(s), Sigma)`` with ``phi(s) = [1, s]`` (``"linear"``) or ``[1, s, s_i s_j]``
(``"quadratic"``). Every ``n_samples_per_update`` episodes, C-REPS solves the dual

    g(eta, v) = eta * epsilon + v^T mean_i psi(s_i) + eta * log(mean_i exp((R_i - v^T psi(s_i)) / eta))

(``psi``: baseline features, ``V(s) = v^T psi(s)`` the context-dependent baseline) with BFGS
on ``log(eta)`` with analytic gradients, weights the episodes by ``exp((R_i - V(s_i)) / eta)`` and refits ``W`` by
weighted ridge regression and ``Sigma`` by the weighted residual covariance (mixed into the old one
with ``covariance_learning_rate``, as in :class:`besdrake.search.reps.GaussianSearch`).

Active context selection (Fabisch & Metzen 2014, "Active contextual policy search"):
:class:`ContextBandit` discretises the context box into a grid of arms and treats the choice of
context as a non-stationary multi-armed bandit whose payoff is the learning progress, the absolute
change of the reward obtained in that context since the last visit, selected with discounted UCB.
Continuous active selection (ACES) is the Bayesian-optimization engineer's part.
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
from scipy.optimize import minimize

from besdrake.search.base import ContextualOptimizer, rng_from_state, rng_state, sanitize_rewards
from besdrake.search.reps import _initial_covariance

FEATURES = ("linear", "quadratic")
_LOG_ETA_LIMIT = 12.0  # eta in [6e-6, 1.6e5] reward standard deviations


def context_features(contexts: np.ndarray, kind: str) -> np.ndarray:
    """Features ``[1, s]`` (``"linear"``) or ``[1, s, s_i s_j (i <= j)]`` (``"quadratic"``) per row."""
    s = np.atleast_2d(np.asarray(contexts, dtype=float))
    columns = [np.ones((s.shape[0], 1)), s]
    if kind == "quadratic":
        i, j = np.triu_indices(s.shape[1])
        columns.append(s[:, i] * s[:, j])
    elif kind != "linear":
        raise ValueError(f"features must be one of {FEATURES}, got {kind!r}")
    return np.hstack(columns)


def _log_softmax(a: np.ndarray) -> tuple[float, np.ndarray]:
    """``logsumexp(a)`` and ``softmax(a)`` (plain numpy: scipy's logsumexp is slow on tiny arrays)."""
    top = a.max()
    e = np.exp(a - top)
    total = e.sum()
    return float(top + np.log(total)), e / total


def creps_weights(rewards: np.ndarray, baseline_features: np.ndarray, epsilon: float) -> tuple[np.ndarray, float, np.ndarray]:
    """Solve the C-REPS dual; returns normalised episode weights, ``eta`` and ``v`` (standardised units)."""
    rewards = np.asarray(rewards, dtype=float)
    scale = float(rewards.std())
    n, k = baseline_features.shape
    if scale == 0.0 or not np.isfinite(scale):
        return np.full(n, 1.0 / n), np.inf, np.zeros(k)
    r = (rewards - rewards.mean()) / scale
    psi = baseline_features
    psi_mean = psi.mean(axis=0)

    def dual(x: np.ndarray) -> tuple[float, np.ndarray]:
        eta = np.exp(np.clip(x[0], -_LOG_ETA_LIMIT, _LOG_ETA_LIMIT))
        v = x[1:]
        a = (r - psi @ v) / eta
        lse, w = _log_softmax(a)
        lse -= np.log(n)
        value = eta * epsilon + v @ psi_mean + eta * lse
        d_eta = epsilon + lse - w @ a
        d_v = psi_mean - w @ psi
        return float(value), np.concatenate([[eta * d_eta], d_v])

    # log(eta) makes the problem unconstrained; BFGS (pure numpy) is much faster than L-BFGS-B's
    # native driver on these tiny problems when the CPU is shared.
    result = minimize(dual, np.zeros(k + 1), jac=True, method="BFGS", options={"gtol": 1e-8})
    eta, v = float(np.exp(np.clip(result.x[0], -_LOG_ETA_LIMIT, _LOG_ETA_LIMIT))), result.x[1:]
    _, w = _log_softmax((r - psi @ v) / eta)
    return w, eta, v


class ContextBandit:
    """Non-stationary bandit over a grid of contexts (arms); payoff = learning progress.

    Parameters
    ----------
    bounds:
        Context box, shape ``(n_context, 2)``.
    n_per_dim:
        Grid points per context dimension (arms: ``n_per_dim ** n_context``).
    discount:
        Discount ``gamma`` of the discounted-UCB statistics (closer to 1: longer memory).
    exploration:
        UCB exploration constant (in units of the learning progress, which is scaled by the
        running mean absolute progress so the constant is dimensionless).
    """

    def __init__(self, bounds: np.ndarray, n_per_dim: int = 5, discount: float = 0.95, exploration: float = 1.0) -> None:
        bounds = np.asarray(bounds, dtype=float)
        if bounds.ndim != 2 or bounds.shape[1] != 2 or not np.isfinite(bounds).all() or (bounds[:, 0] >= bounds[:, 1]).any():
            raise ValueError("context bounds must be a finite (n_context, 2) array with lower < upper")
        if n_per_dim < 1 or not 0 < discount <= 1 or exploration < 0:
            raise ValueError("n_per_dim >= 1, 0 < discount <= 1 and exploration >= 0 are required")
        self.bounds = bounds
        self.n_per_dim = int(n_per_dim)
        self.discount = float(discount)
        self.exploration = float(exploration)
        axes = [np.linspace(lo, hi, self.n_per_dim) if self.n_per_dim > 1 else np.array([(lo + hi) / 2]) for lo, hi in bounds]
        self.arms = np.array(list(itertools.product(*axes)))
        n_arms = len(self.arms)
        self.counts = np.zeros(n_arms)  # discounted visit counts
        self.payoff_sums = np.zeros(n_arms)  # discounted learning-progress sums
        self.last_reward = np.full(n_arms, np.nan)
        self.progress_scale = 0.0

    def select(self, rng: np.random.Generator) -> int:
        """Index of the arm to play next (untried arms first, in random order)."""
        untried = np.flatnonzero(np.isnan(self.last_reward))
        if untried.size:
            return int(rng.choice(untried))
        counts = np.maximum(self.counts, 1e-12)
        mean = self.payoff_sums / counts
        bonus = self.exploration * np.sqrt(2.0 * np.log(max(self.counts.sum(), 1.0 + 1e-12)) / counts)
        score = mean + bonus
        best = np.flatnonzero(score >= score.max() - 1e-12)
        return int(rng.choice(best))

    def arm_of(self, context: np.ndarray) -> int | None:
        """The arm whose grid point is ``context`` (``None`` when it is not a grid point)."""
        distance = np.abs(self.arms - np.asarray(context, dtype=float)).max(axis=1)
        index = int(np.argmin(distance))
        return index if distance[index] <= 1e-9 * (1.0 + np.abs(self.arms).max()) else None

    def update(self, arm: int, reward: float) -> None:
        """Record a reward obtained in ``arm``; its payoff is the change since the arm's last reward."""
        previous = self.last_reward[arm]
        self.last_reward[arm] = reward
        if np.isnan(previous):
            return
        progress = abs(reward - previous)
        self.progress_scale = progress if self.progress_scale == 0 else 0.9 * self.progress_scale + 0.1 * progress
        self.counts *= self.discount
        self.payoff_sums *= self.discount
        self.counts[arm] += 1.0
        self.payoff_sums[arm] += progress / self.progress_scale if self.progress_scale > 0 else 0.0

    def state_dict(self) -> dict[str, Any]:
        return {
            "bounds": self.bounds,
            "n_per_dim": self.n_per_dim,
            "discount": self.discount,
            "exploration": self.exploration,
            "counts": self.counts,
            "payoff_sums": self.payoff_sums,
            "last_reward": self.last_reward,
            "progress_scale": self.progress_scale,
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "ContextBandit":
        bandit = cls(np.asarray(state["bounds"]), state["n_per_dim"], state["discount"], state["exploration"])
        bandit.counts = np.asarray(state["counts"], dtype=float)
        bandit.payoff_sums = np.asarray(state["payoff_sums"], dtype=float)
        bandit.last_reward = np.asarray(state["last_reward"], dtype=float)
        bandit.progress_scale = float(state["progress_scale"])
        return bandit


class CREPS(ContextualOptimizer):
    """C-REPS with a linear-Gaussian upper-level policy (see module docstring).

    Parameters
    ----------
    initial_params:
        Parameters of the initial policy in every context (bias of ``W``), shape ``(n_params,)``.
    n_context:
        Dimension of the context ``s``.
    cov:
        Initial exploration covariance ``Sigma`` (variance, variances or matrix).
    rng:
        The only source of randomness.
    epsilon:
        KL bound per update.
    n_samples_per_update:
        Episodes between two policy updates (default ``max(20, 2 * n_params)``).
    memory:
        Most recent episodes used in an update (default ``n_samples_per_update``: no reuse).
    policy_features, baseline_features:
        ``"linear"`` or ``"quadratic"`` features of the policy mean and of the baseline ``V(s)``.
    ridge:
        Ridge regularisation of the weighted regression for ``W``.
    covariance_learning_rate:
        See :class:`besdrake.search.reps.GaussianSearch` (1 = plain weighted ML).
    context_bounds, active:
        With ``active=True`` and ``context_bounds`` (shape ``(n_context, 2)``), :meth:`select_context`
        picks contexts with a :class:`ContextBandit` over a ``bandit_grid``-point-per-dimension grid.
    """

    def __init__(
        self,
        initial_params: np.ndarray,
        n_context: int,
        cov: float | np.ndarray,
        rng: np.random.Generator,
        *,
        epsilon: float = 1.0,
        n_samples_per_update: int | None = None,
        memory: int | None = None,
        policy_features: str = "linear",
        baseline_features: str = "quadratic",
        ridge: float = 1e-8,
        covariance_learning_rate: float = 0.2,
        context_bounds: np.ndarray | None = None,
        active: bool = False,
        bandit_grid: int = 5,
    ) -> None:
        initial_params = np.asarray(initial_params, dtype=float).ravel()
        if initial_params.size == 0 or not np.isfinite(initial_params).all():
            raise ValueError("initial_params must be a non-empty finite vector")
        if n_context < 1:
            raise ValueError(f"n_context must be >= 1, got {n_context}")
        if not (np.isfinite(epsilon) and epsilon > 0):
            raise ValueError(f"epsilon (KL bound) must be positive, got {epsilon!r}")
        for kind in (policy_features, baseline_features):
            if kind not in FEATURES:
                raise ValueError(f"features must be one of {FEATURES}, got {kind!r}")
        if not 0 < covariance_learning_rate <= 1:
            raise ValueError(f"covariance_learning_rate must be in (0, 1], got {covariance_learning_rate!r}")
        self.n_params = initial_params.size
        self.n_context = int(n_context)
        self.rng = rng
        self.epsilon = float(epsilon)
        self.n_samples_per_update = int(n_samples_per_update or max(20, 2 * self.n_params))
        self.memory = int(memory or self.n_samples_per_update)
        if self.n_samples_per_update < 2 or self.memory < self.n_samples_per_update:
            raise ValueError("n_samples_per_update must be >= 2 and memory >= n_samples_per_update")
        self.policy_features = policy_features
        self.baseline_features = baseline_features
        self.ridge = float(ridge)
        self.covariance_learning_rate = float(covariance_learning_rate)
        n_features = context_features(np.zeros(self.n_context), policy_features).shape[1]
        self.W = np.zeros((n_features, self.n_params))
        self.W[0] = initial_params
        self.cov = _initial_covariance(cov, self.n_params)
        self.contexts = np.zeros((0, self.n_context))
        self.params = np.zeros((0, self.n_params))
        self.rewards = np.zeros(0)
        self.n_episodes = 0
        self.n_updates = 0
        self._since_update = 0
        self._worst_reward: float | None = None
        self.last_eta = np.nan
        self.active = bool(active)
        self.bandit: ContextBandit | None = None
        if active:
            if context_bounds is None:
                raise ValueError("active context selection needs context_bounds")
            self.bandit = ContextBandit(context_bounds, n_per_dim=bandit_grid)
            if self.bandit.bounds.shape[0] != self.n_context:
                raise ValueError(f"context_bounds must have shape ({self.n_context}, 2)")
        self._bandit_grid = int(bandit_grid)

    # -- policy -----------------------------------------------------------------------------------
    def _check_context(self, context: np.ndarray) -> np.ndarray:
        context = np.asarray(context, dtype=float).ravel()
        if context.size != self.n_context or not np.isfinite(context).all():
            raise ValueError(f"context must be a finite vector of length {self.n_context}, got {context!r}")
        return context

    def policy(self, context: np.ndarray) -> np.ndarray:
        """Mean of the upper-level policy: ``W^T phi(s)``; accepts ``(n_context,)`` or ``(n, n_context)``."""
        context = np.asarray(context, dtype=float)
        single = context.ndim == 1
        out = context_features(context, self.policy_features) @ self.W
        return out[0] if single else out

    def ask(self, context: np.ndarray) -> np.ndarray:
        context = self._check_context(context)
        return self.rng.multivariate_normal(self.policy(context), self.cov, method="eigh")

    def select_context(self, bounds: np.ndarray) -> np.ndarray:
        """Bandit choice over the grid when ``active``; otherwise uniform within ``bounds``."""
        bounds = np.asarray(bounds, dtype=float)
        if self.bandit is None:
            return super().select_context(bounds)
        if bounds.shape != self.bandit.bounds.shape or not np.allclose(bounds, self.bandit.bounds):
            raise ValueError(f"bounds {bounds.tolist()} differ from the bandit's context_bounds {self.bandit.bounds.tolist()}")
        return self.bandit.arms[self.bandit.select(self.rng)].copy()

    def tell(self, context: np.ndarray, params: np.ndarray, reward: float) -> None:
        """Record one episode; a NaN/inf reward is a failed episode (penalised, kept)."""
        context = self._check_context(context)
        params = np.asarray(params, dtype=float).ravel()
        if params.size != self.n_params or not np.isfinite(params).all():
            raise ValueError(f"params must be a finite vector of length {self.n_params}")
        clean, _ = sanitize_rewards(np.array([reward], dtype=float), self._worst_reward)
        value = float(clean[0])
        self._worst_reward = value if self._worst_reward is None else min(self._worst_reward, value)
        if self.bandit is not None:
            arm = self.bandit.arm_of(context)
            if arm is not None:
                self.bandit.update(arm, value)
        self.contexts = np.vstack([self.contexts, context])[-self.memory :]
        self.params = np.vstack([self.params, params])[-self.memory :]
        self.rewards = np.append(self.rewards, value)[-self.memory :]
        self.n_episodes += 1
        self._since_update += 1
        if self._since_update >= self.n_samples_per_update:
            self._update()

    def _update(self) -> None:
        psi = context_features(self.contexts, self.baseline_features)
        weights, self.last_eta, _ = creps_weights(self.rewards, psi, self.epsilon)
        phi = context_features(self.contexts, self.policy_features)
        weighted = phi * weights[:, None]
        gram = phi.T @ weighted + self.ridge * np.eye(phi.shape[1])
        W = np.linalg.solve(gram, weighted.T @ self.params)
        residual = self.params - phi @ W
        cov_fit = (weights[:, None] * residual).T @ residual
        c = self.covariance_learning_rate
        cov = (1 - c) * self.cov + c * 0.5 * (cov_fit + cov_fit.T)
        self.cov = cov + 1e-14 * max(float(np.trace(cov)) / self.n_params, 1e-300) * np.eye(self.n_params)
        self.W = W
        self.n_updates += 1
        self._since_update = 0

    # -- persistence ------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        return {
            "type": "CREPS",
            "config": {
                "n_context": self.n_context,
                "epsilon": self.epsilon,
                "n_samples_per_update": self.n_samples_per_update,
                "memory": self.memory,
                "policy_features": self.policy_features,
                "baseline_features": self.baseline_features,
                "ridge": self.ridge,
                "covariance_learning_rate": self.covariance_learning_rate,
                "active": self.active,
                "bandit_grid": self._bandit_grid,
            },
            "W": self.W,
            "cov": self.cov,
            "contexts": self.contexts,
            "params": self.params,
            "rewards": self.rewards,
            "n_episodes": self.n_episodes,
            "n_updates": self.n_updates,
            "since_update": self._since_update,
            "worst_reward": self._worst_reward,
            "rng": rng_state(self.rng),
            "bandit": None if self.bandit is None else self.bandit.state_dict(),
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "CREPS":
        if state.get("type") != "CREPS":
            raise ValueError(f"not a CREPS state (type={state.get('type')!r})")
        cfg = dict(state["config"])
        bandit_state = state["bandit"]
        W = np.asarray(state["W"], dtype=float)
        opt = cls(
            W[0],
            cfg.pop("n_context"),
            np.asarray(state["cov"]),
            rng_from_state(state["rng"]),
            context_bounds=None if bandit_state is None else np.asarray(bandit_state["bounds"]),
            **cfg,
        )
        opt.W = W
        opt.contexts = np.asarray(state["contexts"], dtype=float).reshape(-1, opt.n_context)
        opt.params = np.asarray(state["params"], dtype=float).reshape(-1, opt.n_params)
        opt.rewards = np.asarray(state["rewards"], dtype=float).ravel()
        opt.n_episodes = int(state["n_episodes"])
        opt.n_updates = int(state["n_updates"])
        opt._since_update = int(state["since_update"])
        opt._worst_reward = None if state["worst_reward"] is None else float(state["worst_reward"])
        if bandit_state is not None:
            opt.bandit = ContextBandit.from_state(bandit_state)
        return opt
