"""The result of one throw: :class:`Outcome` (release, touchdown, ball path, joint trajectories, flags)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

FLAG_NAMES = ("dropped_early", "never_released", "joint_limit_exceeded", "sim_failed")


@dataclass
class Outcome:
    """What one rollout produced. SI units; positions in the world frame (floor z = 0, throws go +x).

    * ``release_time`` (s), ``release_position``/``release_velocity`` (3,): the ball's state at the last
      instant it was pushed by the scoop (None when never released or failed).
    * ``touchdown`` (2,): (x, y) where the ball first touches the floor; ``touchdown_time`` (s from start).
    * ``ball_t``/``ball_path`` (M,)/(M, 3): the ball's centre from start to touchdown (simulated, then flight).
    * ``joint_t``/``q_commanded``/``q_measured``: the plan and the encoder readings (K,)/(K, n) while simulated.
    * ``flags``: ``dropped_early`` (left with less than the scenario's min speed), ``never_released``,
      ``joint_limit_exceeded`` (plan or measured angle beyond a position limit, or plan beyond a velocity
      limit), ``sim_failed`` (solver error or divergence; ``message`` says why).
    """

    release_time: float | None = None
    release_position: np.ndarray | None = None
    release_velocity: np.ndarray | None = None
    touchdown: np.ndarray | None = None
    touchdown_time: float | None = None
    ball_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ball_path: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    joint_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    q_commanded: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    q_measured: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    flags: dict[str, bool] = field(default_factory=lambda: {k: False for k in FLAG_NAMES})
    message: str = ""
    effects: dict[str, dict[str, float]] = field(default_factory=dict)
    scenario: str = ""
    sim_time: float = 0.0

    @property
    def ok(self) -> bool:
        """True when the ball was thrown and landed and no flag is raised."""
        return self.touchdown is not None and not any(self.flags.values())

    @property
    def landing_distance(self) -> float | None:
        """Horizontal distance (m) of the touchdown point from the world origin, or None."""
        return None if self.touchdown is None else float(np.hypot(*self.touchdown))

    def summary(self) -> dict[str, Any]:
        """Short JSON-ready summary (no trajectories)."""

        def arr(x):
            return None if x is None else np.asarray(x).tolist()

        raised = [k for k, v in self.flags.items() if v]
        return {
            "ok": self.ok,
            "flags": raised,
            "touchdown_m": arr(self.touchdown),
            "touchdown_time_s": self.touchdown_time,
            "release_time_s": self.release_time,
            "release_position_m": arr(self.release_position),
            "release_velocity_mps": arr(self.release_velocity),
            "release_speed_mps": None if self.release_velocity is None else float(np.linalg.norm(self.release_velocity)),
            "message": self.message,
            "scenario": self.scenario,
            "effects": self.effects,
        }

    def to_dict(self) -> dict[str, Any]:
        """Everything as JSON-ready lists (see :meth:`from_dict`)."""
        d = self.summary()
        d.update(
            {
                "flag_values": dict(self.flags),
                "ball_t": self.ball_t.tolist(),
                "ball_path": self.ball_path.tolist(),
                "joint_t": self.joint_t.tolist(),
                "q_commanded": self.q_commanded.tolist(),
                "q_measured": self.q_measured.tolist(),
                "sim_time_s": self.sim_time,
            }
        )
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Outcome":
        def opt(key):
            return None if d.get(key) is None else np.asarray(d[key], dtype=float)

        return cls(
            release_time=d.get("release_time_s"),
            release_position=opt("release_position_m"),
            release_velocity=opt("release_velocity_mps"),
            touchdown=opt("touchdown_m"),
            touchdown_time=d.get("touchdown_time_s"),
            ball_t=np.asarray(d.get("ball_t", []), dtype=float),
            ball_path=np.asarray(d.get("ball_path", []), dtype=float).reshape(-1, 3),
            joint_t=np.asarray(d.get("joint_t", []), dtype=float),
            q_commanded=_rows(d.get("q_commanded", [])),
            q_measured=_rows(d.get("q_measured", [])),
            flags={k: bool(d.get("flag_values", {}).get(k, False)) for k in FLAG_NAMES},
            message=d.get("message", ""),
            effects=d.get("effects", {}),
            scenario=d.get("scenario", ""),
            sim_time=float(d.get("sim_time_s", 0.0)),
        )

    def to_json(self) -> str:
        return json.dumps(self.to_dict())


def _rows(values) -> np.ndarray:
    """A JSON list of joint rows as an (K, n) array ((0, 0) when empty)."""
    arr = np.asarray(values, dtype=float)
    return arr.reshape(0, 0) if arr.size == 0 else arr.reshape(len(arr), -1)
