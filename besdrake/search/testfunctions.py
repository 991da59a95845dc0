"""Standard test problems for the optimizers of :mod:`besdrake.search`.

``sphere`` and ``rosenbrock`` are costs (minimum 0); the optimizers maximise, so use
:func:`reward_of` to get a batch reward function. :class:`ContextualQuadratic` is a contextual
problem whose optimal parameters depend linearly on the context.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


def sphere(x: np.ndarray) -> np.ndarray:
    """``sum x_i^2`` over the last axis; minimum 0 at the origin."""
    x = np.asarray(x, dtype=float)
    return np.sum(x**2, axis=-1)


def rosenbrock(x: np.ndarray) -> np.ndarray:
    """Rosenbrock's banana function over the last axis (n >= 2); minimum 0 at ``(1, ..., 1)``."""
    x = np.asarray(x, dtype=float)
    if x.shape[-1] < 2:
        raise ValueError("rosenbrock needs at least 2 dimensions")
    return np.sum(100.0 * (x[..., 1:] - x[..., :-1] ** 2) ** 2 + (1.0 - x[..., :-1]) ** 2, axis=-1)


def rastrigin(x: np.ndarray) -> np.ndarray:
    """Multimodal Rastrigin function; minimum 0 at the origin (for restart tests)."""
    x = np.asarray(x, dtype=float)
    return 10.0 * x.shape[-1] + np.sum(x**2 - 10.0 * np.cos(2 * np.pi * x), axis=-1)


def reward_of(cost: Callable[[np.ndarray], np.ndarray]) -> Callable[[np.ndarray], np.ndarray]:
    """Batch reward ``-cost(candidates)`` for candidates of shape ``(n, n_params)``."""

    def reward(candidates: np.ndarray) -> np.ndarray:
        return -cost(np.atleast_2d(candidates))

    return reward


@dataclass
class ContextualQuadratic:
    """Reward ``-(theta - theta*(s))^T diag(h) (theta - theta*(s))`` with ``theta*(s) = A s + b``.

    The maximum reward is 0 in every context, so the regret of parameters ``theta`` in context
    ``s`` is ``-reward(s, theta)``.
    """

    A: np.ndarray  # (n_params, n_context)
    b: np.ndarray  # (n_params,)
    h: np.ndarray  # (n_params,) positive curvatures

    def __post_init__(self) -> None:
        self.A = np.atleast_2d(np.asarray(self.A, dtype=float))
        self.b = np.asarray(self.b, dtype=float).ravel()
        self.h = np.asarray(self.h, dtype=float).ravel()
        if self.A.shape[0] != self.b.size or self.h.size != self.b.size:
            raise ValueError("A, b and h must agree on n_params")
        if (self.h <= 0).any():
            raise ValueError("curvatures h must be positive")

    @property
    def n_params(self) -> int:
        return self.b.size

    @property
    def n_context(self) -> int:
        return self.A.shape[1]

    @classmethod
    def random(cls, n_params: int, n_context: int, rng: np.random.Generator, condition: float = 10.0) -> "ContextualQuadratic":
        """A random instance with curvatures log-spaced in ``[1, condition]``."""
        return cls(rng.normal(size=(n_params, n_context)), rng.normal(size=n_params), np.logspace(0, np.log10(condition), n_params))

    def optimum(self, context: np.ndarray) -> np.ndarray:
        """Optimal parameters for ``context`` (shape ``(n_context,)`` or ``(n, n_context)``)."""
        return np.asarray(context, dtype=float) @ self.A.T + self.b

    def reward(self, context: np.ndarray, params: np.ndarray) -> np.ndarray | float:
        diff = np.asarray(params, dtype=float) - self.optimum(context)
        value = -np.sum(self.h * diff**2, axis=-1)
        return float(value) if np.ndim(value) == 0 else value

    def regret(self, context: np.ndarray, params: np.ndarray) -> np.ndarray | float:
        """Reward lost against the optimum (>= 0)."""
        value = self.reward(context, params)
        return -value
