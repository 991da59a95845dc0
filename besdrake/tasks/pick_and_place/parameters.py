"""Flat parameter vector <-> grasp skill, for policy search (CMA-ES) in simulation.

What refinement may change, and why (everything else stays as imitated):

* ``approach.goal`` (3, m, task frame): where the tool closes on the box: the grasp's accuracy;
* ``transport.goal`` (3, m): where the box is put down (and the hand's release): the place's accuracy;
* ``approach.tau``, ``transport.tau`` (s): the execution times (the robot's speed, how gently the box is lifted
  and set down);
* ``close_lead`` (s): how long before the approach ends the gripper starts to close (the close time is
  ``approach.tau - close_lead``, so it moves with the approach's time); the open time keeps its
  demonstrated delay after the transport's end;
* with ``weights=True`` (default) the **position** forcing-term weights of both segments (the path's
  shape: the lift's height, the clearance over the shelf's edge). The orientation DMPs are not
  refined: the box must stay upright, and the demonstrated hand orientation already carries it so.

Order: ``approach.goal.{x,y,z}``, ``approach.tau``, ``transport.goal.{x,y,z}``, ``transport.tau``,
``close_lead``, then (with weights) ``approach.w.{x,y,z}.{i}`` and ``transport.w.{x,y,z}.{i}``
(dimension-major). With 20 weights per dimension that is 9 + 120 = 129 entries (9 without weights).

Normalisation for the optimizer (``theta = theta0 + scale * x``, as
:class:`besdrake.search.refinement.ParameterScaling`): one unit is :data:`GOAL_UNIT` m for a goal,
:data:`TIME_FRACTION` of the imitated time for an execution time, :data:`CLOSE_UNIT` s for the close
lead and, for a weight, the change that alters the acceleration by :data:`ACCELERATION_UNIT` m/s^2 at
its basis centre (``tau**2 / centre``). Bounds: goals within :data:`GOAL_BOUND` m of the imitated ones,
execution times within [0.5, 2] x the imitated, the close lead within [0, max(1 s, imitated + 0.2 s)],
weights within +-:data:`WEIGHT_BOUND_UNITS` units.
"""

from __future__ import annotations

import numpy as np

from besdrake.tasks.pick_and_place.imitation import GraspImitationError, GraspSkill

GOAL_UNIT = 0.02  # m
GOAL_BOUND = 0.10  # m
TIME_FRACTION = 0.1
CLOSE_UNIT = 0.1  # s
ACCELERATION_UNIT = 0.5  # m/s^2 at a basis centre
WEIGHT_BOUND_UNITS = 50.0
_AXES = ("x", "y", "z")


class GraspParameterization:
    """Maps ``theta`` to copies of a template :class:`GraspSkill` (see the module docstring)."""

    def __init__(self, template: GraspSkill, weights: bool = True) -> None:
        self.template = template.copy()
        self.weights = bool(weights)
        self.n_w = template.approach.position.n_weights_per_dim
        names = []
        for seg in ("approach", "transport"):
            names += [f"{seg}.goal.{a}" for a in _AXES] + [f"{seg}.tau"]
        names.append("close_lead")
        if self.weights:
            for seg in ("approach", "transport"):
                names += [f"{seg}.w.{a}.{i}" for a in _AXES for i in range(self.n_w)]
        self.names: tuple[str, ...] = tuple(names)
        self._open_delay = template.open_time - template.duration

    @property
    def n_params(self) -> int:
        return len(self.names)

    def to_vector(self, skill: GraspSkill | None = None) -> np.ndarray:
        """``theta`` of ``skill`` (default: the template)."""
        s = self.template if skill is None else skill
        parts = []
        for dmp in (s.approach, s.transport):
            parts += [dmp.position.goal, [dmp.execution_time]]
        parts.append([s.approach.execution_time - s.close_time])
        if self.weights:
            parts += [s.approach.position.get_weights(), s.transport.position.get_weights()]
        return np.concatenate(parts)

    def from_vector(self, theta: np.ndarray) -> GraspSkill:
        """A copy of the template with ``theta`` applied; :class:`GraspImitationError` names a bad entry."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (self.n_params,):
            raise GraspImitationError(f"theta must have shape ({self.n_params},), got {theta.shape}")
        bad = np.flatnonzero(~np.isfinite(theta))
        if bad.size:
            raise GraspImitationError(f"theta entry {self.names[bad[0]]} is {theta[bad[0]]} (NaN or infinite)")
        for i in (3, 7):
            if theta[i] <= 0:
                raise GraspImitationError(f"theta entry {self.names[i]} must be > 0 s, got {theta[i]}")
        s = self.template.copy()
        s.approach.position.goal, s.approach.execution_time = theta[0:3], theta[3]
        s.transport.position.goal, s.transport.execution_time = theta[4:7], theta[7]
        s.close_time = float(theta[3] - theta[8])
        s.open_time = float(s.duration + self._open_delay)
        if self.weights:
            k = 3 * self.n_w
            s.approach.position.set_weights(theta[9 : 9 + k])
            s.transport.position.set_weights(theta[9 + k : 9 + 2 * k])
        return s

    def scaling(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(theta0, scale, bounds)`` of the optimizer's normalisation (module docstring); bounds (n, 2)."""
        theta0 = self.to_vector()
        scale, lo, hi = [], [], []
        for i in range(2):
            goal, tau = theta0[4 * i : 4 * i + 3], theta0[4 * i + 3]
            scale += [GOAL_UNIT] * 3 + [TIME_FRACTION * tau]
            lo += list(goal - GOAL_BOUND) + [0.5 * tau]
            hi += list(goal + GOAL_BOUND) + [2.0 * tau]
        lead = theta0[8]
        scale.append(CLOSE_UNIT)
        lo.append(0.0)
        hi.append(max(1.0, lead + 0.2))
        if self.weights:
            for dmp in (self.template.approach, self.template.transport):
                w = dmp.position.get_weights()
                w_scale = np.tile(ACCELERATION_UNIT * dmp.execution_time**2 / dmp.position.basis.centers, 3)
                scale += list(w_scale)
                lo += list(w - WEIGHT_BOUND_UNITS * w_scale)
                hi += list(w + WEIGHT_BOUND_UNITS * w_scale)
        return theta0, np.array(scale), np.column_stack([lo, hi])
