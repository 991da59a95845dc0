"""Input checks shared by the DMP modules: finite numbers, shapes, positive times."""

from __future__ import annotations

import numpy as np


class DMPParameterError(ValueError):
    """A DMP meta-parameter, weight or demonstration is invalid (NaN, wrong shape, out of range)."""


def finite_array(name: str, value: object, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a float array of ``shape`` (a scalar broadcasts), or a clear error."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise DMPParameterError(f"{name} must be numeric, got {value!r}") from err
    if arr.ndim == 0:
        arr = np.full(shape, float(arr))
    if arr.shape != shape:
        raise DMPParameterError(f"{name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise DMPParameterError(f"{name} contains NaN or infinite values: {arr.ravel()[~np.isfinite(arr.ravel())][:3]}")
    return arr


def positive_float(name: str, value: object) -> float:
    """``value`` as a finite float > 0, or a clear error."""
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError) as err:
        raise DMPParameterError(f"{name} must be a number, got {value!r}") from err
    if not np.isfinite(number) or number <= 0.0:
        raise DMPParameterError(f"{name} must be finite and > 0, got {number}")
    return number


def demonstration(t: object, y: object, n_dims: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Check a demonstration: times (N,) strictly increasing, positions (N, n_dims), all finite."""
    t_arr = np.asarray(t, dtype=float)
    y_arr = np.asarray(y, dtype=float)
    if t_arr.ndim != 1 or t_arr.size < 3:
        raise DMPParameterError(f"demonstration times must be a 1-D array of >= 3 samples, got shape {t_arr.shape}")
    if y_arr.ndim != 2 or y_arr.shape[0] != t_arr.size:
        raise DMPParameterError(
            f"demonstration positions must have shape ({t_arr.size}, n_dims), got {y_arr.shape}"
        )
    if n_dims is not None and y_arr.shape[1] != n_dims:
        raise DMPParameterError(f"demonstration has {y_arr.shape[1]} dimensions, the DMP has {n_dims}")
    if not (np.all(np.isfinite(t_arr)) and np.all(np.isfinite(y_arr))):
        raise DMPParameterError("demonstration contains NaN or infinite values")
    if np.any(np.diff(t_arr) <= 0.0):
        raise DMPParameterError("demonstration times must be strictly increasing")
    return t_arr, y_arr
