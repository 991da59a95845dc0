"""The normalised parameter space of refinement: :class:`ParameterScaling` maps the optimizer's ``x`` to the DMP's
``theta`` and back (``theta = theta0 + scale * x``).

One unit is :data:`~besdrake.search.refinement.settings.POSITION_UNIT` rad for start/goal,
:data:`~besdrake.search.refinement.settings.TIME_UNIT` s for the execution time and, for each weight, the weight
change that changes the joint's acceleration by :data:`~besdrake.search.refinement.settings.ACCELERATION_UNIT`
rad/s^2 at its basis centre (weights act through ``z * w / tau^2`` with the phase ``z`` decaying to 0.01, so late
weights need ~100 times larger steps; imitated weights range over 1e0...1e4). Bounds: start and goal within the
joint position limits, execution time in [``MIN_EXECUTION_TIME``, ``MAX_EXECUTION_TIME``] s, weights within
+-``WEIGHT_BOUND_UNITS`` units of the imitated value.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from besdrake.imitation import DMP, DMPParameterization
from besdrake.search.refinement.settings import (ACCELERATION_UNIT, MAX_EXECUTION_TIME, MIN_EXECUTION_TIME, POSITION_UNIT,
                                                 TIME_UNIT, WEIGHT_BOUND_UNITS, RefinementError)

@dataclass
class ParameterScaling:
    """``theta = theta0 + scale * x``; ``bounds`` (n, 2) are in theta units."""

    theta0: np.ndarray
    scale: np.ndarray
    bounds: np.ndarray

    def __post_init__(self) -> None:
        self.theta0 = np.asarray(self.theta0, dtype=float).ravel()
        self.scale = np.asarray(self.scale, dtype=float).ravel()
        self.bounds = np.asarray(self.bounds, dtype=float).reshape(-1, 2)
        n = self.theta0.size
        if self.scale.shape != (n,) or self.bounds.shape != (n, 2):
            raise RefinementError(f"scaling needs theta0 ({n},), scale ({n},), bounds ({n}, 2); got {self.scale.shape}, {self.bounds.shape}")
        if not (np.isfinite(self.theta0).all() and np.isfinite(self.scale).all() and (self.scale > 0).all()):
            raise RefinementError("scaling: theta0 must be finite and every scale finite and > 0")
        if np.isnan(self.bounds).any() or (self.bounds[:, 0] >= self.bounds[:, 1]).any():
            raise RefinementError("scaling: bounds must be ordered (lower < upper) without NaN")

    @classmethod
    def for_dmp(
        cls,
        dmp: DMP,
        position_limits: np.ndarray,
        position_unit: float = POSITION_UNIT,
        acceleration_unit: float = ACCELERATION_UNIT,
        time_unit: float = TIME_UNIT,
        max_execution_time: float | None = None,
    ) -> "ParameterScaling":
        """Scaling around the imitated ``dmp`` (see the module docstring for the units and bounds) within the robot's
        ``position_limits`` (n, 2) rad;
        ``max_execution_time`` (s) replaces :data:`MAX_EXECUTION_TIME` as the upper bound of the
        execution time (e.g. the imitated one: never slower than the imitated movement)."""
        for name, v in (("position_unit", position_unit), ("acceleration_unit", acceleration_unit), ("time_unit", time_unit)):
            if not (np.isfinite(v) and v > 0):
                raise RefinementError(f"{name} must be a finite number > 0, got {v!r}")
        t_max = MAX_EXECUTION_TIME if max_execution_time is None else float(max_execution_time)
        if not (np.isfinite(t_max) and MIN_EXECUTION_TIME < t_max <= MAX_EXECUTION_TIME):
            raise RefinementError(f"max_execution_time must lie in ({MIN_EXECUTION_TIME}, {MAX_EXECUTION_TIME}] s, got {max_execution_time!r}")
        n, k = dmp.n_dims, dmp.n_weights_per_dim
        param = DMPParameterization(dmp)
        theta0 = param.to_vector()
        tau = float(np.clip(dmp.execution_time, MIN_EXECUTION_TIME, t_max))
        theta0[-1] = tau
        centers = dmp.basis.centers  # phase at each basis centre
        w_scale = np.tile(acceleration_unit * tau**2 / centers, n)
        scale = np.concatenate([np.full(2 * n, position_unit), w_scale, [time_unit]])
        limits = np.asarray(position_limits, dtype=float)
        if limits.shape != (n, 2):
            raise RefinementError(f"position_limits must have shape ({n}, 2) for the DMP's {n} joints, got {limits.shape}")
        w = theta0[2 * n : 2 * n + n * k]
        bounds = np.vstack(
            [
                limits,
                limits,
                np.column_stack([w - WEIGHT_BOUND_UNITS * w_scale, w + WEIGHT_BOUND_UNITS * w_scale]),
                [[MIN_EXECUTION_TIME, t_max]],
            ]
        )
        theta0[: 2 * n] = np.clip(theta0[: 2 * n], np.tile(limits[:, 0], 2), np.tile(limits[:, 1], 2))
        return cls(theta0, scale, bounds)

    def covering(self, others: "list[ParameterScaling]") -> "ParameterScaling":
        """This scaling with bounds that hold every one of ``others``' bounds too (the same ``theta0`` and units): one
        space for several imitated movements, each searched within its own bounds."""
        bounds = self.bounds.copy()
        for o in others:
            if o.bounds.shape != bounds.shape:
                raise RefinementError(f"cannot cover bounds of shape {o.bounds.shape} with {bounds.shape}")
            bounds[:, 0] = np.minimum(bounds[:, 0], o.bounds[:, 0])
            bounds[:, 1] = np.maximum(bounds[:, 1], o.bounds[:, 1])
        return ParameterScaling(self.theta0.copy(), self.scale.copy(), bounds)

    @property
    def x_bounds(self) -> np.ndarray:
        """Bounds in the normalised space."""
        return (self.bounds - self.theta0[:, None]) / self.scale[:, None]

    def to_theta(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        return np.clip(self.theta0 + self.scale * x, self.bounds[:, 0], self.bounds[:, 1])

    def to_x(self, theta: np.ndarray) -> np.ndarray:
        theta = np.clip(np.asarray(theta, dtype=float), self.bounds[:, 0], self.bounds[:, 1])
        return (theta - self.theta0) / self.scale

    def to_dict(self) -> dict[str, Any]:
        return {"theta0": self.theta0.tolist(), "scale": self.scale.tolist(), "bounds": self.bounds.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ParameterScaling":
        try:
            return cls(np.asarray(d["theta0"]), np.asarray(d["scale"]), np.asarray(d["bounds"]))
        except (KeyError, TypeError, ValueError) as err:
            raise RefinementError(f"bad scaling record: {err}") from err
