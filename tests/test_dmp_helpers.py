"""Shared helpers of the DMP tests: load the ``movement_primitives`` oracle, demonstration data.

``movement_primitives.dmp`` imports ``pytransform3d`` at module level (an optional dependency of
that package). When it is missing we import the oracle with placeholder ``pytransform3d`` modules
that raise on use, and remove them from ``sys.modules`` again. The joint-space oracle
(``DMPWithFinalVelocity``) and the compiled quaternion step do not use pytransform3d; tests that
need pytransform3d itself skip.
"""

from __future__ import annotations

import sys
import types

import numpy as np

_PT3D = ("pytransform3d.rotations", "pytransform3d.batch_rotations", "pytransform3d.transformations")


def has_pytransform3d() -> bool:
    try:
        import pytransform3d.rotations  # noqa: F401
    except ImportError:
        return False
    return True


def oracle():
    """The ``movement_primitives.dmp`` module."""
    if "movement_primitives.dmp" in sys.modules or has_pytransform3d():
        import movement_primitives.dmp as mp

        return mp
    package = types.ModuleType("pytransform3d")
    package.__path__ = []  # a package, so that submodule imports resolve to the placeholders
    placeholders = {"pytransform3d": package}
    for full_name in _PT3D:
        module = types.ModuleType(full_name)

        def __getattr__(name: str, _module: str = full_name):
            raise ImportError(f"{_module}.{name}: pytransform3d is not installed")

        module.__getattr__ = __getattr__
        setattr(package, full_name.split(".")[1], module)
        placeholders[full_name] = module
    sys.modules.update(placeholders)
    try:
        import movement_primitives.dmp as mp
    finally:
        for name in placeholders:
            sys.modules.pop(name, None)
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
