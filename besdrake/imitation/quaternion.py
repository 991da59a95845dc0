"""Unit-quaternion helpers (w, x, y, z; Hamilton product), vectorised over leading axes.

The logarithm here lives on the 3-sphere, not on SO(3): ``rotation_vector(q)`` returns an angle in
``[0, 2 pi]``, so ``q`` and ``-q`` give different results (angle ``theta`` and ``2 pi - theta``
about opposite axes). Orientation DMPs need that: the sign of ``goal * conj(y)`` encodes whether the
remaining rotation is shorter or longer than pi. (A log that wraps to ``[0, pi]`` makes any demonstrated
rotation beyond pi take the short way instead.)
"""

from __future__ import annotations

import numpy as np

#: Below this norm of the vector part a rotation is treated as the identity (or a full turn).
_SMALL = 1e-12


def multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p * q`` (apply ``q`` first, then ``p``, for active rotations)."""
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    w = p[..., :1] * q[..., :1] - np.sum(p[..., 1:] * q[..., 1:], axis=-1, keepdims=True)
    v = p[..., :1] * q[..., 1:] + q[..., :1] * p[..., 1:] + np.cross(p[..., 1:], q[..., 1:])
    return np.concatenate((w, v), axis=-1)


def conjugate(q: np.ndarray) -> np.ndarray:
    """Conjugate ``(w, -x, -y, -z)``: the inverse rotation of a unit quaternion."""
    q = np.asarray(q, dtype=float)
    return np.concatenate((q[..., :1], -q[..., 1:]), axis=-1)


def from_rotation_vector(r: np.ndarray) -> np.ndarray:
    """Unit quaternion of the rotation by angle ``|r|`` (rad) about ``r / |r|`` (``exp(r / 2)``)."""
    r = np.asarray(r, dtype=float)
    angle = np.linalg.norm(r, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(half) / angle, with its limit 1/2 at angle -> 0.
    scale = np.where(angle > _SMALL, np.sin(half) / np.where(angle > _SMALL, angle, 1.0), 0.5)
    return np.concatenate((np.cos(half), scale * r), axis=-1)


def rotation_vector(q: np.ndarray) -> np.ndarray:
    """``2 log(q)``: rotation vector with angle in ``[0, 2 pi]`` (not wrapped, see module doc).

    A full turn (``q = -1``) has no defined axis and returns zeros.
    """
    q = np.asarray(q, dtype=float)
    w = q[..., :1]
    v = q[..., 1:]
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    safe_n = np.where(n > _SMALL, n, 1.0)
    factor = np.where(n > _SMALL, 2.0 * np.arctan2(n, w) / safe_n, np.where(w > 0, 2.0 / np.where(w > 0, w, 1.0), 0.0))
    return factor * v


def make_continuous(q: np.ndarray) -> np.ndarray:
    """Flip signs along a sequence ``(N, 4)`` so that neighbours have a non-negative dot product."""
    q = np.array(q, dtype=float)
    dots = np.sum(q[1:] * q[:-1], axis=1)
    flips = np.concatenate(([1.0], np.cumprod(np.where(dots < 0.0, -1.0, 1.0))))
    return q * flips[:, None]


def unit(name: str, q: np.ndarray, tolerance: float = 1e-3) -> np.ndarray:
    """``q`` (shape (..., 4), finite, norm within ``tolerance`` of 1) normalised, or a ValueError."""
    from besdrake.imitation._validation import DMPParameterError

    q = np.array(q, dtype=float)
    if q.shape[-1:] != (4,):
        raise DMPParameterError(f"{name} must be quaternions (w, x, y, z) with last axis 4, got shape {q.shape}")
    if not np.all(np.isfinite(q)):
        raise DMPParameterError(f"{name} contains NaN or infinite values")
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(np.abs(norm - 1.0) > tolerance):
        raise DMPParameterError(f"{name} is not a unit quaternion (norm {norm.ravel()[np.argmax(np.abs(norm - 1.0))]:.6g})")
    return q / norm
