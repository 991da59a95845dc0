"""Drake adapters: a DMP rollout as a ``PiecewisePolynomial`` (for a ``TrajectorySource``), and
``DmpSource``, a ``LeafSystem`` that integrates a DMP online as a discrete-update system."""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, Context, DiscreteValues, EventStatus, LeafSystem
from pydrake.trajectories import PiecewisePolynomial

from besdrake.imitation._validation import positive_float
from besdrake.imitation.dmp import DMP, DMPTrajectory


def to_piecewise_polynomial(trajectory: DMPTrajectory) -> PiecewisePolynomial:
    """Cubic Hermite through the rollout's positions with the DMP's velocities (rows: dimensions)."""
    return PiecewisePolynomial.CubicHermite(trajectory.t, trajectory.y.T, trajectory.yd.T)


def dmp_piecewise_polynomial(dmp: DMP, dt: float = 0.01, run_time: float | None = None) -> PiecewisePolynomial:
    """Roll ``dmp`` out every ``dt`` s and interpolate it for a ``TrajectorySource``."""
    return to_piecewise_polynomial(dmp.open_loop(dt, run_time))


class DmpSource(LeafSystem):
    """Integrates a :class:`DMP` online: state ``[y, yd]``, updated every ``dt`` s from ``start_time``.

    Output ports: ``position`` (n), ``velocity`` (n) and ``state`` (2n, ``[y, yd]``, e.g. a
    controller's desired state; the same layout as a ``TrajectorySource`` with
    ``output_derivative_order=1``). Before ``start_time`` it outputs the start position and start
    velocity. Over ``[start_time + k dt, start_time + (k + 1) dt)`` the outputs are the DMP's
    position and sample-time velocity at ``k dt`` (zero-order hold; equal to
    :meth:`DMP.open_loop` sampled every ``dt``).

    Optional input port ``goal`` (n): when connected, it replaces the DMP's goal at every update
    (online adaptation of the meta-parameter; the moving goal is recomputed each step).
    """

    def __init__(self, dmp: DMP, dt: float = 0.001, start_time: float = 0.0) -> None:
        super().__init__()
        self._dmp = dmp.copy()
        self._dt = positive_float("dt", dt)
        self._start_time = float(start_time)
        n = self._dmp.n_dims
        self._n = n
        initial = np.concatenate(self._dmp.start_state(self._dt))
        self._state_index = self.DeclareDiscreteState(initial)
        self._goal_port = self.DeclareVectorInputPort("goal", n)
        self.DeclarePeriodicDiscreteUpdateEvent(self._dt, 0.0, self._update)
        self._before_start = np.concatenate((self._dmp.start, self._dmp.start_velocity))
        depends = {self.xd_ticket(), self.time_ticket()}
        self.DeclareVectorOutputPort("position", n, self._output_position, depends)
        self.DeclareVectorOutputPort("velocity", n, self._output_velocity, depends)
        self.DeclareVectorOutputPort("state", 2 * n, self._output_state, depends)

    @property
    def dmp(self) -> DMP:
        """A copy of the integrated DMP."""
        return self._dmp.copy()

    def _update(self, context: Context, discrete_state: DiscreteValues) -> EventStatus:
        # The update at time t produces the state for DMP time t - start_time, so that the output
        # over [t, t + dt) is the DMP at t (a zero-order hold without a one-step lead).
        x = context.get_discrete_state(self._state_index).get_value()
        t_from = context.get_time() - self._start_time - self._dt
        if t_from < -1e-9:
            return EventStatus.DidNothing()
        goal = self._goal_port.Eval(context) if self._goal_port.HasValue(context) else None
        y, yd = self._dmp.step(t_from, x[: self._n], x[self._n :], self._dt, goal=goal)
        discrete_state.get_mutable_vector(self._state_index).SetFromVector(np.concatenate((y, yd)))
        return EventStatus.Succeeded()

    def _state(self, context: Context) -> np.ndarray:
        if context.get_time() < self._start_time - 1e-12:
            return self._before_start
        return context.get_discrete_state(self._state_index).get_value()

    def _output_position(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self._state(context)[: self._n])

    def _output_velocity(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self._state(context)[self._n :])

    def _output_state(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self._state(context))
