"""Flat parameter vector <-> joint-space DMP, for policy search.

For an arm of n joints and k weights per joint the vector has 2n + nk + 1 entries, in this order:
start (n joint positions, rad), goal (n, rad), forcing-term weights (k per joint, joint-major) and
the execution time (1, s); for n = 6, k = 6 that is 49. The goal velocity, gains and
basis are fixed by the template DMP (from imitation).
"""

from __future__ import annotations

import numpy as np

from besdrake.imitation._validation import DMPParameterError, positive_float
from besdrake.imitation.dmp import DMP

#: Minimum execution time (s) the paper imposes on imitated movements (applied by the embodiment stage;
#: a DMP itself accepts any positive time).
MIN_IMITATED_EXECUTION_TIME = 0.95
#: Forcing-term weights per joint of an imitated DMP (the paper's 6 per joint).
WEIGHTS_PER_JOINT = 6


class DMPParameterization:
    """Maps ``theta`` (start, goal, weights, execution time) to copies of a template :class:`DMP`;
    ``joint_names`` (the robot's arm joints) name the entries and the motion plans (default ``joint1``...)."""

    def __init__(self, template: DMP, joint_names: tuple[str, ...] | None = None) -> None:
        if not isinstance(template, DMP):
            raise TypeError(f"template must be a besdrake.imitation.DMP, got {type(template).__name__}")
        self.template = template.copy()
        n, k = template.n_dims, template.n_weights_per_dim
        if joint_names is not None and len(joint_names) != n:
            raise DMPParameterError(f"joint_names {list(joint_names)} do not match the DMP's {n} dimensions")
        self.joint_names = tuple(joint_names) if joint_names is not None else None
        joints = list(joint_names) if joint_names is not None else [f"joint{i + 1}" for i in range(n)]
        self.names: tuple[str, ...] = tuple(
            [f"start.{j}" for j in joints]
            + [f"goal.{j}" for j in joints]
            + [f"weight.{j}.{i}" for j in joints for i in range(k)]
            + ["execution_time"]
        )
        self._slices = {
            "start": slice(0, n),
            "goal": slice(n, 2 * n),
            "weights": slice(2 * n, 2 * n + n * k),
            "execution_time": 2 * n + n * k,
        }

    @property
    def n_params(self) -> int:
        """Length of ``theta`` (49 for 6 joints and 6 weights per joint)."""
        return len(self.names)

    def to_vector(self, dmp: DMP | None = None) -> np.ndarray:
        """``theta`` of ``dmp`` (default: the template)."""
        dmp = self.template if dmp is None else dmp
        if dmp.n_dims != self.template.n_dims or dmp.n_weights_per_dim != self.template.n_weights_per_dim:
            raise DMPParameterError("the DMP's dimensions differ from the template's")
        return np.concatenate((dmp.start, dmp.goal, dmp.get_weights(), [dmp.execution_time]))

    def from_vector(self, theta: np.ndarray) -> DMP:
        """A copy of the template with ``theta`` applied; :class:`DMPParameterError` names any bad entry."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (self.n_params,):
            raise DMPParameterError(f"theta must have shape ({self.n_params},), got {theta.shape}")
        bad = np.flatnonzero(~np.isfinite(theta))
        if bad.size:
            listed = ", ".join(f"{self.names[i]}={theta[i]}" for i in bad[:5])
            raise DMPParameterError(f"theta has {bad.size} NaN or infinite entries: {listed}")
        s = self._slices
        tau = theta[s["execution_time"]]
        if tau <= 0.0:
            raise DMPParameterError(f"theta entry execution_time must be > 0 s, got {tau}")
        dmp = self.template.copy()
        dmp.start = theta[s["start"]]
        dmp.goal = theta[s["goal"]]
        dmp.set_weights(theta[s["weights"]])
        dmp.execution_time = tau
        return dmp

    def represents(self, dmp: DMP) -> bool:
        """Whether ``theta`` of ``dmp`` gives ``dmp`` back: it differs from the template only in the entries of
        ``theta`` (two imitated movements differ in their goal velocities too, so one cannot stand for the other)."""
        import json

        try:
            back = self.from_vector(self.to_vector(dmp))
        except DMPParameterError:
            return False
        return json.dumps(back.to_dict(), sort_keys=True) == json.dumps(dmp.to_dict(), sort_keys=True)

    def motion_plan(self, theta: np.ndarray, dt: float = 0.002, run_time: float | None = None):
        """Roll the DMP of ``theta`` out every ``dt`` s as a :class:`besdrake.plan.MotionPlan`
        (positions and the DMP's velocities; duration: the execution time unless ``run_time``)."""
        from besdrake.plan import MotionPlan

        dmp = self.from_vector(theta)
        if run_time is not None:
            run_time = positive_float("run_time", run_time)
        traj = dmp.open_loop(positive_float("dt", dt), run_time)
        return MotionPlan(
            t=traj.t, q=traj.y, qd=traj.yd, meta={"source": "dmp", "execution_time": dmp.execution_time},
            joint_names=self.joint_names,
        )


def shared_parameterization(dmps: list[DMP], joint_names: tuple[str, ...] | None = None) -> tuple[DMPParameterization, list[int]]:
    """One search space for several seed DMPs: the parameterization of the first (put the best first) and the indices
    of the seeds it represents (:meth:`DMPParameterization.represents`); a DMP imitated from another demonstration has other
    fixed parts (goal velocity) and is no seed of that search."""
    if not dmps:
        raise DMPParameterError("no DMPs given")
    param = DMPParameterization(dmps[0], joint_names)
    return param, [i for i, d in enumerate(dmps) if param.represents(d)]
