"""Canonical system and radial basis functions of the DMP forcing term.

The phase decays as ``z(t) = exp(-alpha_z t / tau)`` and reaches ``z = 0.01`` at the execution
time ``tau``. Basis centres sit at the phase values of equally spaced times in ``[0, tau]``, so
they do not depend on ``tau``; each Gaussian has the value ``OVERLAP`` at the next centre. The
forcing term is ``f(z) = z * sum_i w_i psi_i(z) / sum_i psi_i(z)``. These choices are those of
the ``movement_primitives`` package (our test oracle).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Value of the phase at the execution time.
FINAL_PHASE = 0.01
#: Decay constant of the canonical system, chosen so that ``z(tau) = FINAL_PHASE``.
ALPHA_Z = float(-np.log(FINAL_PHASE))
#: Value of one basis function at the neighbouring centre.
OVERLAP = 0.8


def phase(t: np.ndarray | float, execution_time: float, alpha_z: float = ALPHA_Z) -> np.ndarray:
    """Phase ``z`` at time(s) ``t`` in s (time 0 is the start of the movement)."""
    return np.exp(-alpha_z * np.asarray(t, dtype=float) / execution_time)


@dataclass(frozen=True)
class RadialBasis:
    """Normalised Gaussian basis over the phase; ``features(z)`` is the forcing term's design matrix."""

    centers: np.ndarray
    widths: np.ndarray

    @classmethod
    def with_count(cls, n_weights: int, alpha_z: float = ALPHA_Z, overlap: float = OVERLAP) -> "RadialBasis":
        """``n_weights`` (>= 2) Gaussians evenly spaced in time over the execution."""
        if int(n_weights) != n_weights or n_weights < 2:
            raise ValueError(f"the number of weights per dimension must be an integer >= 2, got {n_weights}")
        centers = np.exp(-alpha_z * np.arange(n_weights) / (n_weights - 1))
        widths = np.empty(n_weights)
        widths[:-1] = -np.log(overlap) / np.diff(centers) ** 2
        widths[-1] = widths[-2]
        return cls(centers, widths)

    @property
    def n_weights(self) -> int:
        return self.centers.size

    def features(self, z: np.ndarray) -> np.ndarray:
        """``(len(z), n_weights)``: ``z`` times the normalised activations, so ``f = features @ w``."""
        z = np.atleast_1d(np.asarray(z, dtype=float))
        act = np.exp(-self.widths * (z[:, None] - self.centers) ** 2)
        # Far from every centre (only with hundreds of narrow Gaussians) all activations underflow;
        # the forcing term is then zero instead of NaN.
        total = np.maximum(act.sum(axis=1), np.finfo(float).tiny)
        return act * (z / total)[:, None]
