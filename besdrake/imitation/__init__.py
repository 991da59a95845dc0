"""Imitation: dynamical movement primitives (joint space and Cartesian).

* :class:`DMP` -- joint-space DMP with a goal velocity (Muelling et al. 2011/2013): ``fit`` a
  demonstration, meta-parameters ``start``/``goal``/``goal_velocity``/``execution_time``,
  ``open_loop`` rollouts, single ``step``s, ``get_weights``/``set_weights``.
* :class:`QuaternionDMP` (Ude et al. 2014) and :class:`CartesianDMP` (position + orientation).
* :class:`DMPParameterization` -- the 49-parameter vector policy search refines, and
  ``motion_plan(theta, dt)`` -> :class:`besdrake.plan.MotionPlan`.
* :func:`save_dmp` / :func:`load_dmp` -- JSON persistence of any of them.
* :mod:`besdrake.imitation.drake` -- ``PiecewisePolynomial`` adapter and the ``DmpSource`` LeafSystem
  (imported on demand, so this package does not load pydrake).
"""

from besdrake.imitation._validation import DMPParameterError
from besdrake.imitation.cartesian import CartesianDMP, CartesianTrajectory
from besdrake.imitation.dmp import DMP, DMPTrajectory
from besdrake.imitation.io import load_dmp, save_dmp
from besdrake.imitation.orientation import OrientationTrajectory, QuaternionDMP
from besdrake.imitation.policy import MIN_IMITATED_EXECUTION_TIME, WEIGHTS_PER_JOINT, DMPParameterization, shared_parameterization

__all__ = [
    "CartesianDMP",
    "CartesianTrajectory",
    "DMP",
    "DMPParameterError",
    "DMPParameterization",
    "DMPTrajectory",
    "MIN_IMITATED_EXECUTION_TIME",
    "OrientationTrajectory",
    "QuaternionDMP",
    "WEIGHTS_PER_JOINT",
    "load_dmp",
    "save_dmp",
    "shared_parameterization",
]
