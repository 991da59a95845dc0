"""Shared helpers of the DMP tests: the ``movement_primitives`` oracle, demonstration data."""

from __future__ import annotations

import numpy as np


def oracle():
    """The ``movement_primitives.dmp`` module (a test dependency, with pytransform3d)."""
    import movement_primitives.dmp as mp

    return mp


def throw_demo(duration: float = 1.2, n: int = 241) -> tuple[np.ndarray, np.ndarray]:
    """A smooth 6-joint throw-like demonstration that ends moving (non-zero final velocity)."""
    t = np.linspace(0.0, duration, n)
    s = t / duration
    phases = np.arange(6)
    q = (
        0.3 * np.sin(np.pi * s[:, None] * (1.0 + 0.2 * phases) + 0.4 * phases)
        + (0.5 - 0.15 * phases) * s[:, None] ** 3
    )
    return t, q


def test_oracle_loads() -> None:
    mp = oracle()
    assert hasattr(mp, "DMPWithFinalVelocity")
