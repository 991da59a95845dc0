"""Cartesian DMP: a position DMP with goal velocity (:class:`.dmp.DMP`, 3-D) plus an orientation
DMP on unit quaternions (:class:`.orientation.QuaternionDMP`), sharing one execution time.

Poses are rows ``(x, y, z, qw, qx, qy, qz)`` with positions in m.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from besdrake.imitation._validation import DMPParameterError, demonstration, finite_array, positive_float
from besdrake.imitation.dmp import DEFAULT_ALPHA_Y, DEFAULT_BETA_Y, DEFAULT_INT_DT, DMP
from besdrake.imitation.orientation import QuaternionDMP


@dataclass
class CartesianTrajectory:
    """Rollout: times (N,) s, poses (N, 7) (m, quaternion w-first), velocities (N, 6) (m/s, rad/s).

    Linear velocities are at the sample times (:class:`.dmp.DMPTrajectory`); angular velocities
    are the orientation integrator's (:class:`.orientation.OrientationTrajectory`)."""

    t: np.ndarray
    pose: np.ndarray
    velocity: np.ndarray


class CartesianDMP:
    """Position DMP (Muelling, with goal velocity) and orientation DMP (Ude) for an end-effector."""

    def __init__(
        self,
        n_weights_per_dim: int = 10,
        execution_time: float = 1.0,
        alpha_y: float = DEFAULT_ALPHA_Y,
        beta_y: float = DEFAULT_BETA_Y,
        int_dt: float = DEFAULT_INT_DT,
    ) -> None:
        self.position = DMP(3, n_weights_per_dim, execution_time, alpha_y, beta_y, int_dt)
        self.orientation = QuaternionDMP(n_weights_per_dim, execution_time, alpha_y, beta_y, int_dt)

    @property
    def execution_time(self) -> float:
        return self.position.execution_time

    @execution_time.setter
    def execution_time(self, value: float) -> None:
        value = positive_float("execution_time", value)
        self.position.execution_time = value
        self.orientation.execution_time = value

    @property
    def start(self) -> np.ndarray:
        """Start pose (7,)."""
        return np.concatenate((self.position.start, self.orientation.start))

    @start.setter
    def start(self, pose: np.ndarray) -> None:
        pose = finite_array("start", pose, (7,))
        self.position.start = pose[:3]
        self.orientation.start = pose[3:]

    @property
    def goal(self) -> np.ndarray:
        """Goal pose (7,)."""
        return np.concatenate((self.position.goal, self.orientation.goal))

    @goal.setter
    def goal(self, pose: np.ndarray) -> None:
        pose = finite_array("goal", pose, (7,))
        self.position.goal = pose[:3]
        self.orientation.goal = pose[3:]

    @property
    def goal_velocity(self) -> np.ndarray:
        """Goal linear velocity (3,) m/s (the orientation DMP ends at rest)."""
        return self.position.goal_velocity

    @goal_velocity.setter
    def goal_velocity(self, value: np.ndarray) -> None:
        self.position.goal_velocity = value

    @property
    def n_weights(self) -> int:
        return self.position.n_weights + self.orientation.n_weights

    def copy(self) -> "CartesianDMP":
        """Independent copy."""
        return CartesianDMP.from_dict(self.to_dict())

    def get_weights(self) -> np.ndarray:
        """Position weights then orientation weights, flat."""
        return np.concatenate((self.position.get_weights(), self.orientation.get_weights()))

    def set_weights(self, weights: np.ndarray) -> None:
        weights = finite_array("weights", weights, (self.n_weights,))
        self.position.set_weights(weights[: self.position.n_weights])
        self.orientation.set_weights(weights[self.position.n_weights :])

    def fit(self, t: np.ndarray, poses: np.ndarray, regularization: float = 0.0,
            start_velocity: np.ndarray | None = None) -> "CartesianDMP":
        """Imitate poses (N, 7) at times (N,) s; ``start_velocity`` (3,) m/s: the linear velocity the
        movement starts with (default: at rest; see :meth:`.dmp.DMP.fit`)."""
        t, poses = demonstration(t, poses)
        if poses.shape[1] != 7:
            raise DMPParameterError(f"poses must have 7 columns (x, y, z, qw, qx, qy, qz), got {poses.shape[1]}")
        self.position.fit(t, poses[:, :3], regularization, start_velocity)
        self.orientation.fit(t, poses[:, 3:], regularization)
        return self

    def open_loop(self, dt: float = 0.01, run_time: float | None = None) -> CartesianTrajectory:
        pos = self.position.open_loop(dt, run_time)
        rot = self.orientation.open_loop(dt, run_time)
        return CartesianTrajectory(pos.t, np.hstack((pos.y, rot.q)), np.hstack((pos.yd, rot.omega)))

    def step(self, t: float, pose: np.ndarray, velocity: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """One step of ``dt`` s from ``pose`` (7,) and ``velocity`` (6,) at DMP time ``t``."""
        pose = finite_array("pose", pose, (7,))
        velocity = finite_array("velocity", velocity, (6,))
        p, v = self.position.step(t, pose[:3], velocity[:3], dt)
        q, w = self.orientation.step(t, pose[3:], velocity[3:], dt)
        return np.concatenate((p, q)), np.concatenate((v, w))

    def to_dict(self) -> dict[str, Any]:
        return {"type": "CartesianDMP", "position": self.position.to_dict(), "orientation": self.orientation.to_dict()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "CartesianDMP":
        try:
            position = DMP.from_dict(data["position"])
            orientation = QuaternionDMP.from_dict(data["orientation"])
        except KeyError as err:
            raise DMPParameterError(f"CartesianDMP description lacks the field {err.args[0]!r}") from err
        if position.n_dims != 3 or position.execution_time != orientation.execution_time:
            raise DMPParameterError("CartesianDMP parts disagree (position must be 3-D, execution times equal)")
        dmp = cls.__new__(cls)
        dmp.position, dmp.orientation = position, orientation
        return dmp
