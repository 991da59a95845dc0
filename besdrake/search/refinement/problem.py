"""The refinement problem: a template DMP, the robot, the task's reward and the normalised parameter space.

:class:`RefinementProblem` turns normalised candidates into motion plans (retimed to keep the joint limits where a
stretch mends them), evaluates batches of them through a rollout executor (:func:`besdrake.sim.make_executor`) and
records every episode (:mod:`besdrake.search.refinement.records`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from besdrake.imitation import DMP, DMPParameterError, DMPParameterization
from besdrake.plan import MotionPlan, PlanError
from besdrake.robot import Robot
from besdrake.search.refinement.records import RewardBreakdown, _append_details, _details_row, failed_breakdown, params_key
from besdrake.search.refinement.robust import RobustCheck
from besdrake.search.refinement.scaling import ParameterScaling
from besdrake.search.refinement.settings import DEFAULT_RETIME, PLAN_DT, RETIME_MARGIN, RETIME_ROUNDS, RefinementError
from besdrake.task import DEFAULT_TASK, get_task


def _phase(value: Any) -> float:
    """A phase of the movement in (0, 1] (:class:`RefinementProblem`'s ``follow_through``), else RefinementError."""
    try:
        phase = float(value)
    except (TypeError, ValueError):
        phase = float("nan")
    if not (np.isfinite(phase) and 0.0 < phase <= 1.0):
        raise RefinementError(f"follow_through must be a phase in (0, 1] of the movement, got {value!r}")
    return phase


def _families(d: dict[str, Any]) -> list[DMP]:
    """The further movements of a problem record (:meth:`RefinementProblem.describe`)."""
    try:
        return [DMP.from_dict(f) for f in d.get("families", [])]
    except (KeyError, TypeError, ValueError) as err:
        raise RefinementError(f"bad problem record: {err}") from err


class RefinementProblem:
    """Refinement of a template DMP towards a target, in the normalised space of :class:`ParameterScaling`.

    ``reward`` scores one rollout (``reward(plan, outcome, limits) -> RewardBreakdown``; it has ``target``,
    ``penalty(plan, limits)`` and ``to_dict()``); default: the reward of ``task`` (:meth:`besdrake.task.Task.reward`,
    ``task`` None: the platform's default task, :data:`besdrake.task.DEFAULT_TASK`).

    ``evaluate(X)`` simulates a batch of normalised candidates (rows of ``X``) with ``executor``
    (anything with ``evaluate(plans) -> list[Outcome]``) and returns one :class:`RewardBreakdown` each.
    Candidates whose DMP cannot be rolled out become failed episodes; an executor that raises fails the batch.
    With ``robust`` (:class:`~besdrake.search.refinement.robust.RobustCheck`) a candidate near the goal is simulated
    again under the setup's scatter and rewarded by its RMS distance over it. ``follow_through`` (a phase in (0, 1]):
    the movement after it no longer changes the outcome, so only the part before it sets the retiming and the rest is
    slowed where it breaks a limit (:meth:`retimed`); the plans are then what a behaviour template with that phase
    plays (:class:`~besdrake.search.templates.MetaDMP`).

    ``families`` (further imitated movements, :meth:`with_families`): a DMP's goal velocity and acceleration are no
    parameters, so one imitated movement cannot stand for another in the template's space (their weights differ by more
    than its bounds too). With families a candidate's last coordinate says which movement's DMP it varies (0: the
    template, k: ``families[k - 1]``) and the optimizer holds it fixed (:attr:`fixed`): a scout or race from another
    imitated movement searches around that movement itself.
    """

    def __init__(
        self,
        robot: Robot,
        template: DMP,
        reward=None,
        scaling: ParameterScaling | None = None,
        dt: float = PLAN_DT,
        retime: bool | None = None,
        task: str | None = None,
        robust: RobustCheck | None = None,
        follow_through: float | None = None,
        families: Sequence[DMP] = (),
        family_follow_through: Sequence[float | None] = (),
    ) -> None:
        if not isinstance(robot, Robot):
            raise RefinementError(f"robot must be a besdrake.robot.Robot, got {type(robot).__name__}")
        if not isinstance(template, DMP):
            raise RefinementError(f"template must be a besdrake.imitation.DMP, got {type(template).__name__}")
        if template.n_dims != robot.n_joints:
            raise RefinementError(f"the DMP has {template.n_dims} dimensions, the robot {robot.name!r} {robot.n_joints} joints")
        self.robot = robot
        self.parameterization = DMPParameterization(template, robot.joint_names)
        for d in families:
            if not isinstance(d, DMP) or d.n_dims != template.n_dims or d.n_weights_per_dim != template.n_weights_per_dim:
                raise RefinementError("every family must be a DMP with the template's dimensions and weights")
        #: the parameterization of each movement a candidate may vary: the template's first
        self.families = [self.parameterization] + [DMPParameterization(d, robot.joint_names) for d in families]
        self.task = DEFAULT_TASK if task is None else str(task)
        self.reward = reward if reward is not None else get_task(self.task).reward()
        self.scaling = scaling if scaling is not None else ParameterScaling.for_dmp(template, robot.position_limits)
        if self.scaling.theta0.size != self.parameterization.n_params:
            raise RefinementError(f"scaling has {self.scaling.theta0.size} parameters, the DMP {self.parameterization.n_params}")
        if not (np.isfinite(dt) and dt > 0):
            raise RefinementError(f"dt must be > 0 s, got {dt!r}")
        self.dt = float(dt)
        self.retime = DEFAULT_RETIME if retime is None else bool(retime)
        if robust is not None and not isinstance(robust, RobustCheck):
            raise RefinementError(f"robust must be a RobustCheck or None, got {type(robust).__name__}")
        self.robust = robust
        self.follow_through = None if follow_through is None else _phase(follow_through)
        if family_follow_through and len(family_follow_through) != len(families):
            raise RefinementError(f"family_follow_through needs one phase per family ({len(families)}), got {len(family_follow_through)}")
        #: each family's follow-through phase (the template's own for families given none)
        self.phases = [self.follow_through] + [None if f is None else _phase(f) for f in family_follow_through or
                                               [self.follow_through] * len(families)]
        self.records: dict[str, RewardBreakdown] = {}

    @property
    def n_params(self) -> int:
        """Length of a candidate: the DMP's parameters, and the family coordinate where there are families."""
        return self.parameterization.n_params + (1 if len(self.families) > 1 else 0)

    @property
    def fixed(self) -> tuple[int, ...]:
        """Coordinates the optimizer holds at a start point's values: the family coordinate (none without families)."""
        return (self.n_params - 1,) if len(self.families) > 1 else ()

    @property
    def x_bounds(self) -> np.ndarray:
        """Bounds of a candidate (:attr:`ParameterScaling.x_bounds`, and the family coordinate's)."""
        b = self.scaling.x_bounds
        return np.vstack([b, [[-0.5, len(self.families) - 0.5]]]) if len(self.families) > 1 else b

    def _split(self, x: np.ndarray) -> tuple[np.ndarray, int]:
        """The normalised DMP parameters of candidate ``x`` and the family of the movement it varies."""
        x = np.asarray(x, dtype=float)
        if len(self.families) == 1:
            return x, 0
        k = int(np.rint(x[-1])) if np.isfinite(x[-1]) else -1
        if not 0 <= k < len(self.families):
            raise DMPParameterError(f"family coordinate {x[-1]!r} names none of the {len(self.families)} movements")
        return x[:-1], k

    def with_families(self, others: Sequence["RefinementProblem"]) -> "RefinementProblem":
        """This problem over its own imitated movement and those of ``others`` (families 1, 2, ...): the same robot,
        reward and settings, the bounds widened to hold each movement's own (:meth:`ParameterScaling.covering`), each
        movement with its own follow-through phase."""
        if not others:
            return self
        return RefinementProblem(self.robot, self.parameterization.template, self.reward,
                                 self.scaling.covering([o.scaling for o in others]), self.dt, retime=self.retime,
                                 task=self.task, robust=self.robust, follow_through=self.follow_through,
                                 families=[o.parameterization.template for o in others],
                                 family_follow_through=[o.follow_through for o in others])

    def family_start(self, k: int, other: "RefinementProblem | None" = None) -> np.ndarray:
        """The candidate of family ``k``'s imitated movement (``other``: the problem it came from, whose ``theta0``
        it is; default this problem's own, family 0)."""
        x = self.scaling.to_x(self.scaling.theta0 if other is None else other.scaling.theta0)
        return np.append(x, float(k)) if len(self.families) > 1 else x

    def dmp(self, x: np.ndarray) -> DMP:
        """The DMP candidate ``x`` plays (retimed where the problem retimes, as evaluated)."""
        theta, _, k = self._theta_and_plan(x)
        return self.families[k].from_vector(theta)

    @property
    def target(self) -> tuple[float, float]:
        return self.reward.target

    def theta(self, x: np.ndarray) -> np.ndarray:
        """DMP parameters of normalised candidate ``x`` (retimed when the problem retimes, see :meth:`retimed`), in the
        parameterization of the movement it varies (:meth:`dmp` gives its DMP)."""
        return self._theta_and_plan(x)[0]

    def retimed(self, theta: np.ndarray) -> np.ndarray:
        """``theta`` with its execution time stretched just enough that the plan keeps every joint's velocity and
        acceleration limit, as the embodiment mapping's temporal scaling does (:mod:`besdrake.embodiment.scaling`):
        stretching by ``k`` divides velocities by ``k`` and accelerations by ``k**2``. Never faster than ``theta``,
        never beyond the execution-time bound. A stretch is kept only when it mends the plan: what a stretch cannot
        mend (the acceleration of the DMP's final approach to its goal velocity, which a stretch does not lower) is
        left to the reward's penalty, on the plan as it was. A ``theta`` without a valid rollout is returned unchanged
        (its evaluation fails as before). With ``follow_through`` only the movement up to that phase sets the stretch,
        and the rest of the plan is slowed where it breaks a limit (:meth:`~besdrake.plan.MotionPlan.with_follow_through_within`,
        as a behaviour template with the same phase plays it)."""
        return self._retime(theta)[0]

    def _retime(self, theta: np.ndarray, family: int = 0) -> tuple[np.ndarray, MotionPlan | None]:
        """:meth:`retimed`, and the motion plan of the returned parameters where it was rolled out on the way (None
        where not: a ``theta`` without a valid rollout), so that a candidate's DMP is rolled out once more at most."""
        theta = np.array(theta, dtype=float)
        upper = self.scaling.bounds[-1, 1]
        stretched = theta.copy()
        first: MotionPlan | None = None  # the plan of theta itself (round 0)
        for round_ in range(RETIME_ROUNDS + 1):
            try:
                plan = self.families[family].motion_plan(stretched, dt=self.dt)
                until = None if self.phases[family] is None else self.phases[family] * plan.duration
                vel, acc = plan.peak_limit_ratios(self.robot.limits, until=until)
            except (DMPParameterError, PlanError, ValueError):
                return theta, None
            first = plan if round_ == 0 else first
            k = max(float(vel.max()), float(np.sqrt(acc.max())))
            if k <= 1.0:
                return stretched, self._with_follow_through(plan, family)
            if not np.isfinite(k) or round_ == RETIME_ROUNDS or stretched[-1] >= upper:
                return theta, self._with_follow_through(first, family)
            stretched[-1] = min(upper, stretched[-1] * k * (1.0 + RETIME_MARGIN))
        return theta, self._with_follow_through(first, family)

    def _with_follow_through(self, plan: MotionPlan, k: int = 0) -> MotionPlan:
        """``plan`` with its follow-through slowed where that keeps the limits (family ``k``'s phase set), else ``plan``."""
        if self.phases[k] is None:
            return plan
        return plan.with_follow_through_within(self.robot.limits, self.phases[k] * plan.duration)

    def _theta_and_plan(self, x: np.ndarray) -> tuple[np.ndarray, MotionPlan | None, int]:
        """DMP parameters of ``x``, their motion plan where retiming rolled it out already (else None) and the family."""
        x, k = self._split(x)
        theta = self.scaling.to_theta(x)
        return (*self._retime(theta, k), k) if self.retime else (theta, None, k)

    def plan(self, x: np.ndarray) -> MotionPlan:
        """Motion plan of normalised candidate ``x`` (raises DMPParameterError/PlanError for a bad one)."""
        theta, plan, k = self._theta_and_plan(x)
        if plan is None:
            plan = self._with_follow_through(self.families[k].motion_plan(theta, dt=self.dt), k)
        return plan.validate()

    def evaluate(self, X: np.ndarray, executor) -> list[RewardBreakdown]:
        X = np.atleast_2d(np.asarray(X, dtype=float))
        plans: list[MotionPlan | None] = []
        out: list[RewardBreakdown | None] = []
        for x in X:
            try:
                if not np.isfinite(x).all():
                    raise DMPParameterError("candidate contains NaN or infinite values")
                plans.append(self.plan(x))
                out.append(None)
            except (DMPParameterError, PlanError, ValueError) as err:
                plans.append(None)
                out.append(failed_breakdown(f"no motion plan: {err}"))
        todo = [i for i, p in enumerate(plans) if p is not None]
        if todo:
            outcomes = executor.evaluate([plans[i] for i in todo])
            if len(outcomes) != len(todo):
                raise RuntimeError(f"executor returned {len(outcomes)} outcomes for {len(todo)} plans")
            for i, o in zip(todo, outcomes):
                out[i] = self.reward(plans[i], o, self.robot.limits)
            if self.robust is not None:
                best = np.inf if self.robust.frontier is None else self._best_objective({params_key(x) for x in X})
                self._check_robust(plans, out, executor, best)
        return [r for r in out if r is not None]

    def _best_objective(self, batch: set[str]) -> float:
        """Minus the best reward of the recorded episodes outside ``batch`` (m; inf where there are none): what a candidate
        must beat to become the run's best. Episodes of the batch itself are left out, so that a generation evaluated
        again on resuming a killed run is checked as it was the first time."""
        rewards = [r.reward for k, r in self.records.items() if k not in batch and np.isfinite(r.reward)]
        return -max(rewards) if rewards else np.inf

    def _check_robust(self, plans: list, out: list, executor, best_objective: float = np.inf) -> None:
        """Replace the records of the candidates near the goal that could become the run's best (its frontier) by their
        robust ones: the probes of every such candidate in one batch of rollouts, then the other setups of those that did
        not stay put in another."""
        check = [i for i, r in enumerate(out) if r is not None and plans[i] is not None and self.robust.needs(r)
                 and self.robust.on_frontier(r, best_objective)]
        if not check:
            return
        probes = self.robust.probes()
        perturbed = {i: [None] * self.robust.n_rollouts for i in check}
        self._simulate_setups(plans, out, executor, [(i, k) for i in check for k in probes], perturbed)
        rest = [k for k in range(self.robust.n_rollouts) if k not in probes]
        moved = [i for i in check if not self.robust.stays_put(out[i], [perturbed[i][k] for k in probes])]
        self._simulate_setups(plans, out, executor, [(i, k) for i in moved for k in rest], perturbed)
        for i in check:
            out[i] = self.robust.combine(out[i], perturbed[i])

    def _simulate_setups(self, plans: list, out: list, executor, jobs: list[tuple[int, int]], perturbed: dict) -> None:
        """Simulate candidate ``i``'s plan in setup ``k`` for every ``(i, k)`` of ``jobs`` (one batch), into ``perturbed``."""
        if not jobs:
            return
        outcomes = executor.evaluate([plans[i] for i, _ in jobs], effects=[self.robust.effects[k] for _, k in jobs])
        if len(outcomes) != len(jobs):
            raise RuntimeError(f"executor returned {len(outcomes)} outcomes for {len(jobs)} plans")
        for (i, k), o in zip(jobs, outcomes):
            perturbed[i][k] = self.reward(plans[i], o, self.robot.limits)

    def batch_evaluator(self, executor, details_path: Path | None = None) -> Callable[[np.ndarray], list[float]]:
        """``evaluate_batch`` for :func:`besdrake.search.loop.run_search`; records every episode
        (in memory and, with ``details_path``, appended to a CSV keyed by :func:`params_key`)."""

        def evaluate_batch(X: np.ndarray) -> list[float]:
            results = self.evaluate(X, executor)
            rows = []
            for x, r in zip(np.atleast_2d(X), results):
                key = params_key(x)
                self.records[key] = r
                rows.append(_details_row(key, r, robust=self.robust is not None))
            if details_path is not None:
                _append_details(details_path, rows, robust=self.robust is not None)
            return [r.reward for r in results]

        return evaluate_batch

    def describe(self) -> dict[str, Any]:
        """JSON record of the problem (template, reward, scaling, dt): enough to rebuild it."""
        return {
            "robot": self.robot.reference,
            "template": self.parameterization.template.to_dict(),
            "reward": self.reward.to_dict(),
            "scaling": self.scaling.to_dict(),
            "dt": self.dt,
            "names": list(self.parameterization.names),
        } | ({"retime": True} if self.retime else {}) | ({"task": self.task} if self.task != DEFAULT_TASK else {}) | (
            {"robust": self.robust.to_dict()} if self.robust is not None else {}) | (
            {"follow_through": self.follow_through} if self.follow_through is not None else {}) | (
            {"families": [p.template.to_dict() for p in self.families[1:]], "family_follow_through": self.phases[1:]}
            if len(self.families) > 1 else {})

    @classmethod
    def from_description(cls, d: dict[str, Any]) -> "RefinementProblem":
        from besdrake.robot import RobotError, load_robot

        try:
            template = DMP.from_dict(d["template"])
            robot = load_robot(d["robot"])
        except (KeyError, TypeError, ValueError, RobotError) as err:
            raise RefinementError(f"bad problem record: {err}") from err
        task = str(d.get("task", DEFAULT_TASK))
        return cls(robot, template, get_task(task).reward_from_dict(d["reward"]), ParameterScaling.from_dict(d["scaling"]),
                   float(d["dt"]), retime=bool(d.get("retime", False)), task=task,
                   robust=RobustCheck.from_dict(d["robust"]) if d.get("robust") is not None else None,
                   follow_through=d.get("follow_through"), families=_families(d), family_follow_through=d.get("family_follow_through", ()))
