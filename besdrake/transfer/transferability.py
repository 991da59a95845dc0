"""The Transferability Approach (Koos et al. 2013) as the BesMan paper applies it (sections 2.5, 3.1.5).

A multi-objective evolutionary search over motion-plan parameters, seeded with plans refined in
simulation, minimises three objectives at once:

1. the target distance of the touchdown **in simulation** (plus a penalty for joint-limit violations), expected over
   the lab's trial-to-trial scatter of the task's setup (``placement_sd``; the task's quadrature over it,
   :meth:`besdrake.task.Task.scatter_effects`, e.g. 9 placements of the object per plan): a plan on a cliff, where a
   few millimetres of setup send the object elsewhere, scores badly even when its nominal trial hits;
2. the simulation-to-reality **disparity predicted by a surrogate** (a Gaussian process over the
   behaviour features the scenario's task describes (:meth:`besdrake.task.Task.behaviour_descriptor`), trained on every plan
   transferred so far: disparity = distance between simulated and measured touchdown);
3. minus the **behavioural diversity** (mean distance to the nearest behaviours of the population
   and of the plans already transferred), which keeps the search exploring.

Selection is NSGA-II (non-dominated sorting, crowding distance); children are Gaussian mutations whose
step is drawn per child between ``mutation_sd_min`` and ``mutation_sd`` (log-uniform, in parameter scales),
so the search looks both far from and right next to the refined plans. After every generation (the paper:
one transfer per 50 simulated episodes, the population size) the update heuristic transfers one
plan to the lab, chosen by ``transfer_choice`` (default ``"likely"``; measured with
``scripts/bench_transferability.py`` on the 4 default subjects whose refined plan landed within
0.16 m in simulation: 3/3 success within 10 transfers for 4 of 4 with ``"likely"``, 2 of 4 with
``"diverse"``):

* ``"diverse"`` (the paper's heuristic): among the non-dominated plans that land within
  ``transfer_max_sim_distance`` of the target in simulation and break no limit, the one whose
  behaviour differs most from everything transferred before (the first transfer: the plan closest
  to the target in simulation).
* ``"predicted"``: the plan of the population (within every limit) whose touchdown **predicted for
  the lab** is closest to the target. The prediction is the simulated touchdown plus the
  sim-to-lab touchdown offset (a vector, m) that a second Gaussian process (:class:`OffsetSurrogate`,
  same descriptors) learns from every lab trial, repetitions included; a plan already run in the lab is
  predicted from its own measurements, so the best plan in the lab is re-tried when nothing else is
  predicted closer. It spends the transfers on the task instead of on exploration: with a
  faithful-enough simulation the paper's diverse choice sends plans 0.1-0.3 m off target on purpose.
* ``"likely"``: the plan most likely to pass the success check, P(``success_repetitions`` of them
  within ``success_radius``) for a touchdown scattering isotropically around the predicted one (Rice
  distribution), averaged over the simulated setups of the scatter (each shifts the touchdown by what it does
  in simulation). The scatter is the lab's (pooled over the plans run more than once, starting
  from ``lab_sd_prior``), and for a plan run before its own measured scatter shrunk towards that: a
  plan on a cliff (e.g. the object sometimes leaves the tool early) that lands on target only now and then
  is no longer re-tried, and one whose simulated placements show the cliff is not tried at all. A lab
  touchdown far (``outlier_radius``) from the median of its plan's touchdowns is a cliff event: a miss
  of that plan, but left out of the lab's pooled scatter and of the offset model, which one such trial
  would otherwise skew for every plan.

Placements, mixed mutation steps and cliff events together, measured with ``scripts/bench_transferability.py``
(refined simulation, population 10, the 10 default subjects x lab seeds 1000-6000): 60 of 60 subject-seed pairs
reach 3/3 within 10 transfers (mean 2.4 transfers, one pair at 10); without them 58 of 60 (subject 1 twice; mean 2.7
with a failure counted as 11, five pairs at 9 or more). The search simulates 9 times the episodes (14-180 s per
subject on one core instead of 2-34 s).

Its measured disparity trains the surrogate. When a transferred plan lands
within ``success_radius`` of the target, it is repeated until ``success_repetitions`` lab trials
say whether it does so reliably (the issue's success criterion: 3 of 3). At the end, the 2 best
plans in the lab and 4 plans of the Pareto front are evaluated ``final_repetitions`` times.

A search may end early as futile (``futility_p``, off by default; ``besdrake learn`` sets 0.01): once each of the last
``futility_transfers`` plans sent to the lab was predicted (``"likely"``, with the offsets the lab has shown) to pass the
success check with a probability below ``futility_p``, no plan of the population is likely to succeed: the lab is off by
more than the search makes up, and lab trials are better spent on a diagnosis. Each transfer records its predicted
probability (``Transfer.p_success``). Measured (session 24, ``scripts/bench_transferability.py --scenario nominal``,
the designed simulation against the default lab, subjects 0-9, population 10, 10 transfers): the 7 searches that reach
3/3 transfer plans of P 0.016-0.64, a near miss (best lab trial 0.080 m) 0.013-0.078; the two hopeless ones (refined
plans 0.31-0.35 m off in simulation) stay below 0.0017 throughout: 0.01 over 3 transfers ends those two after 3 of
their 10 transfers and no other.

Seeds are parameter vectors of one parameterization: plans refined from different demonstrations (other goal
velocities) are not seeds of one search (:func:`besdrake.imitation.shared_parameterization`).

Every lab trial goes through the caller's lab (put a :class:`~besdrake.transfer.lab.SafetyGate` in
front) and, when a :class:`~besdrake.transfer.log.LabLog` is given, is appended to it before it is
used. The search state is saved after every generation; a rerun with the same output folder
resumes, taking trials that the log already holds from the log instead of executing them again.
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from besdrake.plan import MotionPlan
from besdrake.robot import JointLimits
from besdrake.search.base import load_state, rng_from_state, rng_state, save_state
from besdrake.transfer.measurement import Measurement, plan_hash

#: Touchdown "distance" given to a trial that never lands (m): worse than any real one.
NO_TOUCHDOWN_DISTANCE = 5.0
#: How the update heuristic picks the plan to transfer (see the module docstring).
TRANSFER_CHOICES = ("diverse", "predicted", "likely")
#: The lab's setup scatter (m per axis) assumed by default: the built-in lab's documented figure (the diagnosis
#: assumes the same); a real lab measures its own.
PLACEMENT_SD = 0.002
#: Largest placement scatter accepted (m per axis): the virtual lab's largest; the quadrature's outer points
#: (sqrt(3) of it) are clipped by the task to where its setup allows.
MAX_PLACEMENT_SD = 0.005


@dataclass
class TransferabilityConfig:
    """Settings of the Transferability Approach (defaults follow the paper where it gives numbers)."""

    target: tuple[float, float] = (2.0, 0.0)
    population: int = 50
    max_transfers: int = 25
    success_radius: float = 0.1
    success_repetitions: int = 3
    stop_on_success: bool = True
    final_best_in_lab: int = 2
    final_pareto: int = 4
    final_repetitions: int = 3
    mutation_sd: float = 0.3  # in units of the parameter scales: the largest mutation step
    mutation_sd_min: float = 0.02  # the smallest: each child's step is drawn log-uniformly in [min, max]
    transfer_max_sim_distance: float = 0.3
    limit_penalty: float = 1.0  # m of objective per rad (rad/s, rad/s^2) of limit violation
    diversity_neighbours: int = 5
    transfer_choice: str = "likely"  # "likely", "predicted" or "diverse" (the paper's; see the module docstring)
    lab_sd_prior: float = 0.05  # m per axis: the lab's touchdown scatter assumed before repeated plans measure it
    placement_sd: float = PLACEMENT_SD  # m per axis: the lab's trial-to-trial setup scatter (0: nominal only)
    # m: a lab touchdown this far from the median of its plan's (>= 3) touchdowns is a cliff event (the object left
    # early): a miss of that plan, left out of the lab's scatter and of the offset model (None: every trial counts)
    outlier_radius: float | None = 0.25
    # A futile search ends early: with transfer_choice "likely", once the last ``futility_transfers`` plans transferred
    # were each predicted to pass the success check with a probability below ``futility_p`` (the lab is systematically
    # off from the simulation by more than the search can make up; the diagnosis, not more transfers, helps). None: off.
    futility_p: float | None = None
    futility_transfers: int = 3

    def __post_init__(self) -> None:
        counts = {"population": 1, "max_transfers": 1, "success_repetitions": 1, "final_repetitions": 1,
                  "final_best_in_lab": 0, "final_pareto": 0, "diversity_neighbours": 1, "futility_transfers": 1}
        for name, least in counts.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
                raise ValueError(f"{name} must be a whole number >= {least}, got {value!r}")
        if self.transfer_choice not in TRANSFER_CHOICES:
            raise ValueError(f"transfer_choice must be one of {TRANSFER_CHOICES}, got {self.transfer_choice!r}")
        if not (np.isfinite(self.mutation_sd_min) and 0.0 < self.mutation_sd_min <= self.mutation_sd):
            raise ValueError(f"mutation_sd_min must lie in (0, mutation_sd = {self.mutation_sd}], got {self.mutation_sd_min!r}")
        if self.outlier_radius is not None and not (np.isfinite(self.outlier_radius) and self.outlier_radius > 0):
            raise ValueError(f"outlier_radius must be a distance > 0 (m) or None, got {self.outlier_radius!r}")
        if self.futility_p is not None and not (np.isfinite(self.futility_p) and 0.0 < self.futility_p < 1.0):
            raise ValueError(f"futility_p must lie in (0, 1) or be None, got {self.futility_p!r}")
        if not (np.isfinite(self.placement_sd) and 0.0 <= self.placement_sd <= MAX_PLACEMENT_SD):
            raise ValueError(f"placement_sd must be within 0..{MAX_PLACEMENT_SD} m, got {self.placement_sd!r}")


@dataclass
class Transfer:
    """One lab trial of the search."""

    trial: int
    kind: str  # "transfer", "repeat" or "final"
    theta: list[float]
    plan_hash: str
    sim_touchdown: list[float] | None
    lab_touchdown: list[float] | None
    disparity: float
    lab_target_distance: float
    flags: list[str] = field(default_factory=list)
    #: a transferred plan's probability of passing the success check as predicted when it was chosen ("likely")
    p_success: float | None = None


@dataclass
class TransferabilityResult:
    """What the search found and how many lab trials it took."""

    transfers: list[Transfer]
    transfers_until_success: int | None  # lab trials up to and including the last of the 3/3 repetitions
    plans_transferred_until_success: int | None
    final: list[dict[str, Any]]
    best_theta: np.ndarray | None
    generations: int
    sim_episodes: int
    wall_time_s: float
    stopped_futile: bool = False  # ended before max_transfers by the futility rule (TransferabilityConfig.futility_p)

    def summary(self) -> dict[str, Any]:
        reliable = [f for f in self.final if f["reliable"]]
        return {
            "lab_trials": len(self.transfers),
            "transfers_until_success": self.transfers_until_success,
            "plans_transferred_until_success": self.plans_transferred_until_success,
            "generations": self.generations,
            "sim_episodes": self.sim_episodes,
            "final_candidates": self.final,
            "n_reliable_final_candidates": len(reliable),
            "median_disparity_m": float(np.median([t.disparity for t in self.transfers])) if self.transfers else None,
            "best_lab_target_distance_m": min((t.lab_target_distance for t in self.transfers), default=None),
            "stopped_futile": self.stopped_futile,
            "wall_time_s": self.wall_time_s,
        }


class _DescriptorGP:
    """Gaussian-process regression from standardised behaviour descriptors to ``width`` measured values.

    Until ``min_points`` observations exist every behaviour gets their mean (zero before the first)."""

    width = 1
    min_points = 2
    noise = (0.1, (1e-4, 1.0))  # WhiteKernel level and bounds (on the normalised targets)

    def __init__(self) -> None:
        self.X = np.zeros((0, 0))  # (rows, features); the width comes with the first row
        self.T = np.zeros((0, self.width))
        self.keep: np.ndarray | None = None  # rows used (None: all)
        self._gp = None

    def set_keep(self, keep: np.ndarray | None) -> None:
        """Use only the rows where ``keep`` is true (None: all), e.g. without a plan's cliff events."""
        keep = None if keep is None else np.asarray(keep, dtype=bool)
        if (keep is None) != (self.keep is None) or (keep is not None and not np.array_equal(keep, self.keep)):
            self.keep, self._gp = keep, None

    def _rows(self) -> tuple[np.ndarray, np.ndarray]:
        if self.keep is None or len(self.keep) != len(self.T):
            return self.X, self.T
        return self.X[self.keep], self.T[self.keep]

    def _append(self, descriptor: np.ndarray, value) -> None:
        self.X = _stack(self.X, descriptor)
        self.T = np.vstack([self.T, np.asarray(value, dtype=float).reshape(1, self.width)])
        self._gp = None

    def _fit(self):
        from sklearn.exceptions import ConvergenceWarning
        from sklearn.gaussian_process import GaussianProcessRegressor
        from sklearn.gaussian_process.kernels import ConstantKernel, RBF, WhiteKernel

        X, T = self._rows()
        self._mean = X.mean(axis=0)
        scale = X.std(axis=0)
        scale[scale < 1e-9] = 1.0
        self._scale = scale
        level, bounds = self.noise
        kernel = ConstantKernel(1.0, (1e-2, 1e2)) * RBF(length_scale=3.0, length_scale_bounds=(0.3, 100.0)) + WhiteKernel(level, bounds)
        target = T[:, 0] if self.width == 1 else T
        with warnings.catch_warnings():
            # A handful of transfers often puts a hyperparameter on its bound (all noise, or no signal
            # yet): expected early in the search, not worth a warning per fit.
            warnings.simplefilter("ignore", ConvergenceWarning)
            self._gp = GaussianProcessRegressor(kernel, normalize_y=True, random_state=0).fit((X - self._mean) / self._scale, target)

    def _predict(self, descriptors: np.ndarray) -> np.ndarray:
        n = len(descriptors)
        T = self._rows()[1]
        if len(T) < self.min_points:
            return np.tile(T.mean(axis=0) if len(T) else np.zeros(self.width), (n, 1))
        if self._gp is None:
            self._fit()
        return np.asarray(self._gp.predict((descriptors - self._mean) / self._scale)).reshape(n, self.width)


class DisparitySurrogate(_DescriptorGP):
    """Gaussian-process regression from standardised behaviour descriptors to the measured disparity."""

    @property
    def y(self) -> np.ndarray:
        return self.T[:, 0]

    @y.setter
    def y(self, values: np.ndarray) -> None:
        self.T = np.asarray(values, dtype=float).reshape(-1, 1)
        self._gp = None

    def add(self, descriptor: np.ndarray, disparity: float) -> None:
        self._append(descriptor, disparity)

    def predict(self, descriptors: np.ndarray) -> np.ndarray:
        """Predicted disparity (m); before two transfers every behaviour gets the same prediction."""
        return self._predict(descriptors)[:, 0]


class OffsetSurrogate(_DescriptorGP):
    """Gaussian-process regression from standardised behaviour descriptors to the lab-minus-simulation
    touchdown offset (x, y; m). Before any lab trial the offset is predicted as zero, with one or two
    trials as their mean offset; the GP's prior mean is the mean measured offset (``normalize_y``), so
    behaviours far from every transferred one get the average offset."""

    width = 2
    min_points = 3
    noise = (0.5, (1e-3, 10.0))

    @property
    def Y(self) -> np.ndarray:
        return self.T

    @Y.setter
    def Y(self, values: np.ndarray) -> None:
        self.T = np.asarray(values, dtype=float).reshape(-1, 2)
        self._gp = None

    def add(self, descriptor: np.ndarray, offset: np.ndarray) -> None:
        self._append(descriptor, offset)

    def predict(self, descriptors: np.ndarray) -> np.ndarray:
        """Predicted offsets ``(n, 2)`` (m)."""
        return self._predict(descriptors)


def nondominated_ranks(F: np.ndarray) -> np.ndarray:
    """Pareto rank (0 = non-dominated) of each row of the objective matrix ``F`` (minimised)."""
    n = len(F)
    le = (F[:, None, :] <= F[None, :, :]).all(axis=2)
    lt = (F[:, None, :] < F[None, :, :]).any(axis=2)
    dominates = le & lt  # dominates[i, j]: i dominates j
    ranks = np.full(n, -1)
    remaining = np.ones(n, dtype=bool)
    rank = 0
    while remaining.any():
        dominated = (dominates[remaining][:, remaining]).any(axis=0)
        front = np.flatnonzero(remaining)[~dominated]
        ranks[front] = rank
        remaining[front] = False
        rank += 1
    return ranks


def crowding_distance(F: np.ndarray) -> np.ndarray:
    """NSGA-II crowding distance of the rows of ``F`` (one front)."""
    n, m = F.shape
    dist = np.zeros(n)
    if n <= 2:
        return np.full(n, np.inf)
    for k in range(m):
        order = np.argsort(F[:, k])
        span = F[order[-1], k] - F[order[0], k]
        dist[order[0]] = dist[order[-1]] = np.inf
        if span > 0:
            dist[order[1:-1]] += (F[order[2:], k] - F[order[:-2], k]) / span
    return dist


def _stack(rows: np.ndarray, row: np.ndarray) -> np.ndarray:
    """``rows`` with ``row`` appended (an empty table takes the row's width)."""
    row = np.atleast_2d(np.asarray(row, dtype=float))
    return row.copy() if len(rows) == 0 else np.vstack([rows, row])


def _table(values) -> np.ndarray:
    """A saved table of descriptors as a 2-D array ((0, 0) when empty)."""
    a = np.atleast_2d(np.asarray(values, dtype=float))
    return np.zeros((0, 0)) if a.size == 0 else a


def _novelty(D: np.ndarray, archive: np.ndarray, k: int) -> np.ndarray:
    """Mean distance of each row of ``D`` to its ``k`` nearest neighbours in ``D`` and ``archive``."""
    ref = np.vstack([D, archive]) if len(archive) else D
    mean = ref.mean(axis=0)
    scale = ref.std(axis=0)
    scale[scale < 1e-9] = 1.0
    a, b = (D - mean) / scale, (ref - mean) / scale
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    d.sort(axis=1)
    return d[:, 1 : k + 1].mean(axis=1)  # column 0 is the distance to itself


class TransferabilityApproach:
    """Multi-objective search with transfers to a lab (see the module docstring).

    Args:
        to_plan: parameters -> :class:`MotionPlan` (e.g. ``DMPParameterization(dmp).motion_plan``).
        seeds: ``(k, n)`` parameter vectors refined in simulation (the initial population's core).
        scales: ``(n,)`` typical size of each parameter (mutations are ``mutation_sd * scales``).
        bounds: ``(n, 2)`` lower and upper bounds of the parameters.
        executor: evaluates plans in simulation (``.evaluate(plans) -> list[Outcome]``).
        lab: executes plans in reality (``.execute(plan) -> Measurement``), a safety gate in front.
        rng: the search's only source of randomness.
        log: optional :class:`~besdrake.transfer.log.LabLog`; every lab trial is appended before use.
        out_dir: optional folder for the resumable search state.
        limits: the robot's joint limits (default: those of the lab's robot, else of the executor's scenario).
    """

    def __init__(
        self,
        to_plan: Callable[[np.ndarray], MotionPlan],
        seeds: np.ndarray,
        scales: np.ndarray,
        bounds: np.ndarray,
        executor,
        lab,
        rng: np.random.Generator,
        config: TransferabilityConfig | None = None,
        log=None,
        out_dir: str | Path | None = None,
        progress: Callable[[str], None] | None = None,
        limits: JointLimits | None = None,
    ) -> None:
        self.to_plan = to_plan
        self._limits = limits
        self.seeds = np.atleast_2d(np.asarray(seeds, dtype=float))
        self.scales = np.asarray(scales, dtype=float)
        self.bounds = np.asarray(bounds, dtype=float)
        if self.seeds.shape[1] != len(self.scales) or self.bounds.shape != (len(self.scales), 2):
            raise ValueError("seeds, scales and bounds must agree on the number of parameters")
        if not np.isfinite(self.seeds).all():
            raise ValueError("seed parameters contain NaN or infinite values")
        self.executor = executor
        self.lab = lab
        self.rng = rng
        self.config = config or TransferabilityConfig()
        self.log = log
        self.out_dir = Path(out_dir) if out_dir is not None else None
        self.progress = progress or (lambda msg: None)
        self.target = np.asarray(self.config.target, dtype=float)
        self.surrogate = DisparitySurrogate()
        self.offsets = OffsetSurrogate()
        self._offset_trials: list[int] | None = []  # lab trial of each offset row (None: unknown, an old state)
        self.transfers: list[Transfer] = []
        self.transferred_descriptors = np.zeros((0, 0))
        self._describe = None  # the task's behaviour_descriptor, looked up on first use
        self.sim_episodes = 0
        self.generation = 0
        self.success_at: int | None = None
        self.success_plans: int | None = None
        from besdrake.task import DEFAULT_TASK, get_task

        scenario = getattr(executor, "scenario", None)
        task = get_task(scenario.task if scenario is not None else DEFAULT_TASK)
        self.scatter, self.placement_weights = task.scatter_effects(scenario, self.config.placement_sd)

    @property
    def limits(self) -> JointLimits:
        """The robot's joint limits (given, or the lab's robot's, or the executor's scenario's robot's)."""
        if self._limits is None:
            robot = getattr(self.lab, "robot", None) or getattr(getattr(self.executor, "scenario", None), "robot", None)
            if robot is None:
                raise ValueError("TransferabilityApproach needs limits= (neither the lab nor the executor names a robot)")
            self._limits = robot.limits
        return self._limits

    def describe(self, plan: MotionPlan, outcome) -> np.ndarray:
        """The behaviour features of ``plan`` simulated in ``outcome``, as the executor's scenario's task describes them
        (:meth:`besdrake.task.Task.behaviour_descriptor`)."""
        if self._describe is None:
            from besdrake.task import get_task

            scenario = getattr(self.executor, "scenario", None)
            if scenario is None:
                raise ValueError("TransferabilityApproach needs an executor with a scenario (its task describes behaviours)")
            self._describe = get_task(scenario.task).behaviour_descriptor
        return np.asarray(self._describe(plan, outcome), dtype=float)

    # -- simulation ---------------------------------------------------------------------------
    def _evaluate(self, thetas: np.ndarray) -> tuple[np.ndarray, np.ndarray, list, np.ndarray]:
        """Sim objective, descriptors, outcomes (the scenario's own setup) and scatter shifts of parameter vectors.

        The objective is the target distance expected over the task's setup scatter (:attr:`scatter`; a
        trial that lands nowhere counts :data:`NO_TOUCHDOWN_DISTANCE`) plus the limit penalty. The shifts ``(n, K, 2)``
        are each setup's touchdown minus the one at the habit (m; NaN where either does not land)."""
        plans, penalties = [], np.zeros(len(thetas))
        for i, theta in enumerate(thetas):
            plan = self.to_plan(theta)
            lim = plan.check_limits(self.limits)
            penalties[i] = self.config.limit_penalty * float(lim.position.sum() + lim.velocity.sum() + lim.acceleration.sum())
            plans.append(plan)
        k = len(self.scatter)
        if k == 1:
            runs = self.executor.evaluate(plans)
        else:
            effects = list(self.scatter)
            runs = self.executor.evaluate([p for p in plans for _ in range(k)], effects=effects * len(plans))
        self.sim_episodes += len(runs)
        td = np.array([o.touchdown if o.touchdown is not None else [np.nan, np.nan] for o in runs], dtype=float).reshape(len(plans), k, 2)
        dist = np.linalg.norm(td - self.target, axis=2)
        f1 = np.where(np.isfinite(dist), dist, NO_TOUCHDOWN_DISTANCE) @ self.placement_weights + penalties
        outcomes = runs[::k]
        D = np.array([self.describe(p, o) for p, o in zip(plans, outcomes)])
        return f1, D, outcomes, td - td[:, :1]

    def _mutate(self, parents: np.ndarray) -> np.ndarray:
        """Gaussian mutation, each child with its own step drawn log-uniformly between ``mutation_sd_min`` and
        ``mutation_sd`` (times the scales): large steps explore, small ones search next to a refined plan, whose
        neighbours the large steps rarely hit (a plan on a cliff needs a more robust neighbour)."""
        cfg = self.config
        step = cfg.mutation_sd
        if cfg.mutation_sd_min < cfg.mutation_sd:
            step = np.exp(self.rng.uniform(np.log(cfg.mutation_sd_min), np.log(cfg.mutation_sd), (len(parents), 1)))
        children = parents + step * self.scales * self.rng.standard_normal(parents.shape)
        return np.clip(children, self.bounds[:, 0], self.bounds[:, 1])

    def _objectives(self, f1: np.ndarray, D: np.ndarray) -> np.ndarray:
        f2 = self.surrogate.predict(D)
        f3 = -_novelty(D, self.transferred_descriptors, self.config.diversity_neighbours)
        return np.column_stack([f1, f2, f3])

    def _select(self, F: np.ndarray, n: int) -> np.ndarray:
        ranks = nondominated_ranks(F)
        chosen: list[int] = []
        for r in range(ranks.max() + 1):
            front = np.flatnonzero(ranks == r)
            if len(chosen) + len(front) <= n:
                chosen += front.tolist()
            else:
                crowd = crowding_distance(F[front])
                chosen += front[np.argsort(-crowd)][: n - len(chosen)].tolist()
                break
        return np.array(chosen)

    def _tournament(self, F: np.ndarray, n: int) -> np.ndarray:
        ranks = nondominated_ranks(F)
        a, b = self.rng.integers(0, len(F), n), self.rng.integers(0, len(F), n)
        return np.where(ranks[a] <= ranks[b], a, b)

    # -- the lab --------------------------------------------------------------------------------
    def _lab_trial(self, theta: np.ndarray, kind: str, sim_touchdown: np.ndarray | None, descriptor: np.ndarray | None,
                   p_success: float | None = None) -> Transfer:
        """One lab trial of ``theta``; with ``descriptor`` its measurement trains the surrogates
        (a ``kind == "transfer"`` trial also enters the archive of transferred behaviours); ``p_success``: its predicted
        chance of passing the success check, recorded with the trial."""
        plan = self.to_plan(theta)
        h = plan_hash(plan)
        trial = len(self.transfers)
        m: Measurement | None = None
        if self.log is not None and trial < len(self.log):
            logged = self.log.measurement(trial)
            if plan_hash(logged.plan) != h:
                raise RuntimeError(
                    f"the log's trial {trial} holds another plan than the resumed search proposes: "
                    "the log belongs to another run (use a new --out folder)"
                )
            m = logged
        if m is None:
            m = self.lab.execute(plan, trial=trial)
            if self.log is not None:
                self.log.append(m)  # written to disk before anything uses it
        raised = [k for k, v in m.flags.items() if v]
        lab_td = None if m.touchdown is None else np.asarray(m.touchdown, dtype=float)
        if lab_td is None or sim_touchdown is None:
            disparity = NO_TOUCHDOWN_DISTANCE
        else:
            disparity = float(np.linalg.norm(lab_td - sim_touchdown))
        lab_dist = float(np.linalg.norm(lab_td - self.target)) if lab_td is not None else NO_TOUCHDOWN_DISTANCE
        t = Transfer(
            trial=trial, kind=kind, theta=theta.tolist(), plan_hash=h,
            sim_touchdown=None if sim_touchdown is None else sim_touchdown.tolist(),
            lab_touchdown=None if lab_td is None else lab_td.tolist(),
            disparity=disparity, lab_target_distance=lab_dist, flags=raised, p_success=p_success,
        )
        self.transfers.append(t)
        if descriptor is not None and "refused_by_safety_gate" not in raised:
            self.surrogate.add(descriptor, disparity)
            if kind == "transfer":
                self.transferred_descriptors = _stack(self.transferred_descriptors, descriptor)
            if lab_td is not None and sim_touchdown is not None:
                self.offsets.add(descriptor, lab_td - sim_touchdown)
                if self._offset_trials is not None:
                    self._offset_trials.append(trial)
        self.progress(f"lab trial {trial} ({kind}): target distance {lab_dist:.3f} m, disparity {disparity:.3f} m")
        return t

    def _choose_transfer(self, P: np.ndarray, f1: np.ndarray, F: np.ndarray, D: np.ndarray, sim_td: np.ndarray,
                         shifts: np.ndarray | None = None) -> tuple[int, float | None]:
        """The population index of the plan to transfer and, with ``"likely"``, its predicted chance of passing the
        success check (else None)."""
        limits_ok = np.array([self.to_plan(p).check_limits(self.limits).ok for p in P])
        if self.config.transfer_choice in ("predicted", "likely"):
            return self._closest_predicted(limits_ok, f1, D, sim_td, P, shifts)
        ranks = nondominated_ranks(F)
        pool = np.flatnonzero((ranks == 0) & (f1 <= self.config.transfer_max_sim_distance) & limits_ok)
        if len(pool) == 0:
            pool = np.flatnonzero(limits_ok) if limits_ok.any() else np.arange(len(P))
            return int(pool[np.argmin(f1[pool])]), None
        if len(self.transferred_descriptors) == 0:
            return int(pool[np.argmin(f1[pool])]), None
        ref = np.vstack([D, self.transferred_descriptors])
        scale = ref.std(axis=0)
        scale[scale < 1e-9] = 1.0
        d = np.linalg.norm((D[pool, None, :] - self.transferred_descriptors[None, :, :]) / scale, axis=2).min(axis=1)
        return int(pool[np.argmax(d)]), None

    def predicted_lab_touchdowns(self, D: np.ndarray, sim_td: np.ndarray) -> np.ndarray:
        """Simulated touchdowns ``(n, 2)`` plus the offsets the :class:`OffsetSurrogate` predicts (m), learned
        without the cliff events (:meth:`cliff_trials`)."""
        if self._offset_trials is not None and len(self._offset_trials) == len(self.offsets.Y):
            cliffs = self.cliff_trials()
            self.offsets.set_keep(np.array([t not in cliffs for t in self._offset_trials], dtype=bool))
        return np.asarray(sim_td, dtype=float) + self.offsets.predict(np.atleast_2d(D))

    def _closest_predicted(self, limits_ok: np.ndarray, f1: np.ndarray, D: np.ndarray, sim_td: np.ndarray,
                           P: np.ndarray | None = None, shifts: np.ndarray | None = None) -> tuple[int, float | None]:
        landed = limits_ok & np.isfinite(sim_td).all(axis=1)
        if not landed.any():
            pool = np.flatnonzero(limits_ok) if limits_ok.any() else np.arange(len(f1))
            return int(pool[np.argmin(f1[pool])]), (0.0 if self.config.transfer_choice == "likely" else None)
        pool = np.flatnonzero(landed)
        predicted = self.predicted_lab_touchdowns(D[pool], sim_td[pool])
        sh, w = (np.zeros((len(pool), 1, 2)), np.ones(1)) if shifts is None else (shifts[pool], self.placement_weights)
        if self.config.transfer_choice != "likely" or P is None:
            dist = np.linalg.norm(predicted[:, None, :] + sh - self.target, axis=2)
            return int(pool[np.argmin(np.where(np.isfinite(dist), dist, NO_TOUCHDOWN_DISTANCE) @ w)]), None
        p = self._success_probabilities(P[pool], predicted, sh, w)
        return int(pool[np.argmax(p)]), float(np.max(p))

    def _run_in_lab(self) -> dict[str, list[Transfer]]:
        """The lab trials (transfers and repeats) that landed, by plan hash."""
        groups: dict[str, list[Transfer]] = {}
        for t in self.transfers:
            if t.lab_touchdown is not None and t.kind in ("transfer", "repeat"):
                groups.setdefault(t.plan_hash, []).append(t)
        return groups

    def _lab_groups(self, inliers: bool = False) -> dict[str, np.ndarray]:
        """Measured lab touchdowns ``(k, 2)`` of every plan run so far, by plan hash (``inliers``: without the
        cliff events)."""
        cliffs = self.cliff_trials() if inliers else set()
        groups = {h: [t.lab_touchdown for t in ts if t.trial not in cliffs] for h, ts in self._run_in_lab().items()}
        return {h: np.asarray(v, dtype=float) for h, v in groups.items() if v}

    def cliff_trials(self) -> set[int]:
        """Lab trials (indices) that landed farther than ``outlier_radius`` from the median touchdown of their plan,
        among plans run at least 3 times: the object left the tool early or the like, a miss that no Gaussian scatter
        or offset describes."""
        r = self.config.outlier_radius
        if r is None:
            return set()
        out: set[int] = set()
        for ts in self._run_in_lab().values():
            if len(ts) >= 3:
                v = np.array([t.lab_touchdown for t in ts], dtype=float)
                far = np.linalg.norm(v - np.median(v, axis=0), axis=1) > r
                out.update(t.trial for t, f in zip(ts, far) if f)
        return out

    def _success_probabilities(self, thetas: np.ndarray, predicted: np.ndarray, shifts: np.ndarray | None = None,
                               weights: np.ndarray | None = None) -> np.ndarray:
        """P(every repetition of the success check lands within the radius) of each plan (see ``"likely"``).

        ``shifts`` ``(n, K, 2)``: each scattered setup's touchdown minus the scenario's own, in simulation, with
        ``weights`` ``(K,)``: one trial's probability is their weighted mean around the predicted touchdown (a
        placement that does not land counts as a miss), so a plan on a cliff, where a few millimetres of placement
        send the object elsewhere, is unlikely to pass. A plan run before is centred on its measurements minus the
        mean shift (they already hold the placement scatter). Its cliff events (:meth:`cliff_trials`) are left out of
        its and the pooled scatter and count as misses: one trial's probability is multiplied by (inliers + 1) /
        (trials + 1)."""
        if shifts is None:
            shifts, weights = np.zeros((len(thetas), 1, 2)), np.ones(1)
        from scipy.stats import rice

        cfg = self.config
        groups = self._lab_groups(inliers=True)
        run = {h: len(ts) for h, ts in self._run_in_lab().items()}
        ss, dof = 0.0, 0
        for v in groups.values():
            if len(v) > 1:
                ss += float(((v - v.mean(axis=0)) ** 2).sum())
                dof += 2 * (len(v) - 1)
        prior_dof = 4.0
        var0 = (prior_dof * cfg.lab_sd_prior**2 + ss) / (prior_dof + dof)  # pooled per-axis variance
        out = np.zeros(len(thetas))
        for j, theta in enumerate(thetas):
            h = plan_hash(self.to_plan(theta))
            v = groups.get(h)
            centre, var, kept = predicted[j], var0, 1.0
            landed = np.isfinite(shifts[j]).all(axis=1)
            if h in run:
                kept = (0 if v is None else len(v)) + 1.0
                kept /= run[h] + 1.0
            if v is not None:
                mean = v.mean(axis=0)  # its own measurements say where it lands
                if len(v) > 1:
                    own = float(((v - mean) ** 2).sum())
                    var = (prior_dof * var0 + own) / (prior_dof + 2 * (len(v) - 1))
                var = var * (1.0 + 1.0 / len(v))  # the mean's own uncertainty
                w = weights * landed
                centre = mean - (w @ np.where(landed[:, None], shifts[j], 0.0)) / max(w.sum(), 1e-12)
            sd = np.sqrt(var)
            single = rice.cdf(cfg.success_radius / sd, np.linalg.norm(centre + shifts[j][landed] - self.target, axis=1) / sd)
            out[j] = (kept * float(weights[landed] @ single)) ** cfg.success_repetitions
        return out

    # -- persistence ------------------------------------------------------------------------------
    def _save(self, P: np.ndarray, f1: np.ndarray, D: np.ndarray, sim_td: np.ndarray, shifts: np.ndarray) -> None:
        if self.out_dir is None:
            return
        state = {
            "generation": self.generation,
            "sim_episodes": self.sim_episodes,
            "population": P,
            "f1": f1,
            "descriptors": D,
            "sim_touchdown": sim_td,
            "placement_shifts": shifts,
            "transfers": [asdict(t) for t in self.transfers],
            "surrogate_X": self.surrogate.X,
            "surrogate_y": self.surrogate.y,
            "transferred_descriptors": self.transferred_descriptors,
            "offset_X": self.offsets.X,
            "offset_Y": self.offsets.Y,
            "offset_trials": self._offset_trials,
            "success_at": self.success_at,
            "success_plans": self.success_plans,
            "rng": rng_state(self.rng),
            "config": asdict(self.config),
        }
        save_state(state, self.out_dir / "transferability_state")

    def _load(self):
        if self.out_dir is None or not (self.out_dir / "transferability_state.json").is_file():
            return None
        s = load_state(self.out_dir / "transferability_state")
        # fields added since the state was written: their defaults, the paper's transfer choice (the only one then),
        # the setup as the scenario has it only (the scatter came later), one mutation step and no cliff events
        saved = json.loads(json.dumps(asdict(TransferabilityConfig()))) | {"transfer_choice": "diverse", "placement_sd": 0.0,
                                                                       "mutation_sd_min": s["config"].get("mutation_sd"),
                                                                       "outlier_radius": None} | s["config"]
        if saved != json.loads(json.dumps(asdict(self.config))):
            raise ValueError(f"{self.out_dir} holds a search with other settings: use a new output folder")
        self.generation, self.sim_episodes = int(s["generation"]), int(s["sim_episodes"])
        self.transfers = [Transfer(**t) for t in s["transfers"]]
        self.surrogate.X, self.surrogate.y = _table(s["surrogate_X"]), np.asarray(s["surrogate_y"])
        self.transferred_descriptors = _table(s["transferred_descriptors"])
        if "offset_X" in s:
            self.offsets.X = _table(s["offset_X"])
            self.offsets.Y = np.asarray(s["offset_Y"], dtype=float).reshape(-1, 2)
        self._offset_trials = [int(t) for t in s["offset_trials"]] if s.get("offset_trials") is not None else None
        self.success_at, self.success_plans = s["success_at"], s["success_plans"]
        self.rng = rng_from_state(s["rng"])
        P = np.asarray(s["population"])
        shifts = np.asarray(s["placement_shifts"], dtype=float) if "placement_shifts" in s else np.zeros((len(P), 1, 2))
        return P, np.asarray(s["f1"]), np.asarray(s["descriptors"]), np.asarray(s["sim_touchdown"]), shifts.reshape(len(P), -1, 2)

    # -- the search -------------------------------------------------------------------------------
    def run(self) -> TransferabilityResult:
        cfg = self.config
        t_start = time.perf_counter()
        loaded = self._load()
        if loaded is None:
            n_seed = len(self.seeds)
            extra = self.seeds[self.rng.integers(0, n_seed, max(cfg.population - n_seed, 0))]
            P = np.vstack([self.seeds, self._mutate(extra)])[: max(cfg.population, n_seed)]
            f1, D, outcomes, shifts = self._evaluate(P)
            sim_td = np.array([o.touchdown if o.touchdown is not None else [np.nan, np.nan] for o in outcomes])
        else:
            P, f1, D, sim_td, shifts = loaded
            self.progress(f"resumed at generation {self.generation} with {len(self.transfers)} lab trials")
        n_plans = sum(1 for t in self.transfers if t.kind == "transfer")
        while n_plans < cfg.max_transfers and not (cfg.stop_on_success and self.success_at is not None) and not self.futile():
            self.generation += 1
            F = self._objectives(f1, D)
            children = self._mutate(P[self._tournament(F, cfg.population)])
            cf1, cD, couts, cshifts = self._evaluate(children)
            ctd = np.array([o.touchdown if o.touchdown is not None else [np.nan, np.nan] for o in couts])
            P, f1, D, sim_td = np.vstack([P, children]), np.append(f1, cf1), np.vstack([D, cD]), np.vstack([sim_td, ctd])
            shifts = np.concatenate([shifts, cshifts])
            F = self._objectives(f1, D)
            keep = self._select(F, cfg.population)
            P, f1, D, sim_td, shifts, F = P[keep], f1[keep], D[keep], sim_td[keep], shifts[keep], F[keep]
            i, p_success = self._choose_transfer(P, f1, F, D, sim_td, shifts)
            td = None if np.isnan(sim_td[i]).any() else sim_td[i]
            t = self._lab_trial(P[i], "transfer", td, D[i], p_success)
            n_plans += 1
            if t.lab_target_distance < cfg.success_radius and self.success_at is None:
                hits = 1
                for _ in range(cfg.success_repetitions - 1):
                    r = self._lab_trial(P[i], "repeat", td, D[i])
                    hits += r.lab_target_distance < cfg.success_radius
                if hits == cfg.success_repetitions:
                    self.success_at = len(self.transfers)
                    self.success_plans = n_plans
            self._save(P, f1, D, sim_td, shifts)
        futile = n_plans < cfg.max_transfers and self.futile()
        if futile:
            self.progress(f"no plan is likely to pass the success check (the last {cfg.futility_transfers} transferred each below "
                          f"P = {cfg.futility_p:g}): the search ends after {n_plans} transfers")
        final = self._final_evaluation(P, f1, D, sim_td)
        best = None
        if self.transfers:
            best = np.asarray(min(self.transfers, key=lambda t: t.lab_target_distance).theta)
        return TransferabilityResult(
            transfers=self.transfers,
            transfers_until_success=self.success_at,
            plans_transferred_until_success=self.success_plans,
            final=final,
            best_theta=best,
            generations=self.generation,
            sim_episodes=self.sim_episodes,
            wall_time_s=time.perf_counter() - t_start,
            stopped_futile=futile,
        )

    def futile(self) -> bool:
        """Whether the search is futile (:attr:`TransferabilityConfig.futility_p`): no success yet, and each of the last
        ``futility_transfers`` plans transferred was predicted to pass the success check with a probability below
        ``futility_p`` (decided from the trials, so a resumed search decides the same)."""
        cfg = self.config
        if cfg.futility_p is None or self.success_at is not None:
            return False
        ps = [t.p_success for t in self.transfers if t.kind == "transfer"][-cfg.futility_transfers:]
        return len(ps) == cfg.futility_transfers and all(p is not None and p < cfg.futility_p for p in ps)

    def _final_evaluation(self, P, f1, D, sim_td) -> list[dict[str, Any]]:
        """2 best plans in the lab and 4 of the Pareto front (within every joint limit), each repeated
        ``final_repetitions`` times."""
        cfg = self.config
        candidates: list[tuple[str, np.ndarray, np.ndarray | None]] = []
        lab_plans = {}
        for t in self.transfers:
            if t.kind in ("transfer", "repeat"):
                lab_plans.setdefault(t.plan_hash, []).append(t)
        ranked = sorted(lab_plans.values(), key=lambda ts: np.mean([x.lab_target_distance for x in ts]))
        for ts in ranked[: cfg.final_best_in_lab]:
            td = None if ts[0].sim_touchdown is None else np.asarray(ts[0].sim_touchdown)
            candidates.append(("best_in_lab", np.asarray(ts[0].theta), td))
        F = self._objectives(f1, D)
        front = np.flatnonzero(nondominated_ranks(F) == 0)
        front = front[[self.to_plan(P[i]).check_limits(self.limits).ok for i in front]]  # a plan beyond the limits never reaches the lab
        front = front[np.argsort(F[front, 0] + F[front, 1])][: cfg.final_pareto]
        for i in front:
            candidates.append(("pareto", P[i], None if np.isnan(sim_td[i]).any() else sim_td[i]))
        out = []
        for kind, theta, td in candidates:
            dists = [self._lab_trial(theta, "final", td, None).lab_target_distance for _ in range(cfg.final_repetitions)]
            out.append({
                "kind": kind,
                "lab_target_distances_m": dists,
                "reliable": bool(all(d < cfg.success_radius for d in dists)),
                "sim_target_distance_m": None if td is None else float(np.linalg.norm(td - self.target)),
            })
        return out
