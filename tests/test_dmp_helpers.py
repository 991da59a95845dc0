"""Shared helpers of the DMP tests: load the ``movement_primitives`` oracle, demonstration data.

``movement_primitives.dmp`` imports ``pytransform3d`` at module level (an optional dependency of
that package, not installed here). When it is missing we import the oracle with stand-in
``pytransform3d`` modules, and remove them from ``sys.modules`` again. The joint-space oracle
(``DMPWithFinalVelocity``) and the compiled quaternion step do not use pytransform3d. The
quaternion imitation of ``CartesianDMP`` uses five functions of ``pytransform3d.rotations``; the
stand-in provides them backed by :mod:`scipy.spatial.transform` (independent of our quaternion
code): the log map wraps to [0, pi] like pytransform3d's, and ``quaternion_gradient`` follows
pytransform3d's definition (one-sided differences at the ends, central ones inside). Any other
name raises.
"""

from __future__ import annotations

import sys
import types

import numpy as np

_PT3D = ("pytransform3d.rotations", "pytransform3d.batch_rotations", "pytransform3d.transformations")


def _scipy_rotations(module: types.ModuleType) -> None:
    """Fill ``module`` with scipy-backed versions of the pytransform3d functions the oracle uses."""
    from scipy.spatial.transform import Rotation

    def _rot(q):
        return Rotation.from_quat(np.asarray(q, dtype=float), scalar_first=True)

    def compact_axis_angle_from_quaternion(q):
        return _rot(q).as_rotvec()

    def quaternion_from_compact_axis_angle(a):
        return Rotation.from_rotvec(np.asarray(a, dtype=float)).as_quat(canonical=False, scalar_first=True)

    def concatenate_quaternions(q1, q2):
        return (_rot(q1) * _rot(q2)).as_quat(canonical=False, scalar_first=True)

    def q_conj(q):
        q = np.asarray(q, dtype=float)
        return np.array([q[0], -q[1], -q[2], -q[3]])

    def quaternion_gradient(Q, dt=1.0):
        R = _rot(Q)
        out = np.empty((len(Q), 3))
        out[0] = (R[1] * R[0].inv()).as_rotvec() / dt
        out[1:-1] = (R[2:] * R[:-2].inv()).as_rotvec() / (2.0 * dt)
        out[-1] = (R[-1] * R[-2].inv()).as_rotvec() / dt
        return out

    for fn in (compact_axis_angle_from_quaternion, quaternion_from_compact_axis_angle,
               concatenate_quaternions, q_conj, quaternion_gradient):
        setattr(module, fn.__name__, fn)


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
        if full_name == "pytransform3d.rotations":
            _scipy_rotations(module)
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
