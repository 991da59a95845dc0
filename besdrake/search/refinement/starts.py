"""Where refinement starts: the imitated movements ranked by their reward (:func:`rank_starts`), and a run's problem
over the movements its scouts and races start from with a start point per movement (:func:`family_run`), or their
parameters as start points in the best one's normalised space (:func:`restart_points`, :func:`run_start`: hybrids)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from besdrake.search.refinement.problem import RefinementProblem
from besdrake.search.refinement.records import RewardBreakdown
from besdrake.search.refinement.settings import DEFAULT_SCOUT_STARTS, RefinementError


def best_start(problems: Sequence[RefinementProblem], executor) -> tuple[int, RewardBreakdown]:
    """Index of the imitated movement (x = 0 of each problem) with the highest reward, and its record."""
    return rank_starts(problems, executor)[0]


def rank_starts(problems: Sequence[RefinementProblem], executor) -> list[tuple[int, RewardBreakdown]]:
    """Every imitated movement (x = 0 of each problem) with its record, best reward first (failed ones last). The
    movements are simulated in one batch (:func:`~besdrake.sim.scheduler.run_concurrently`: one rollout each)."""
    from besdrake.sim.scheduler import run_concurrently

    records = run_concurrently(executor, [lambda ex, p=p: p.evaluate(np.zeros((1, p.n_params)), ex)[0] for p in problems])
    results = list(enumerate(records))
    if not any(np.isfinite(r.reward) for _, r in results):
        raise RefinementError("none of the imitated movements could be simulated")
    return sorted(results, key=lambda ir: -ir[1].reward if np.isfinite(ir[1].reward) else np.inf)


def simulated_order(ranking: Sequence[tuple[int, RewardBreakdown]]) -> list[int]:
    """The indices of :func:`rank_starts`'s ``ranking`` whose movement could be simulated, best first: what run starts,
    scouts and restarts draw from."""
    return [int(i) for i, r in ranking if np.isfinite(r.reward)]


def restart_points(problem: RefinementProblem, others: Sequence[RefinementProblem]) -> np.ndarray:
    """The parameters of the imitated movements of ``others`` as candidates of ``problem``'s normalised space, shape
    ``(len(others), n_params)`` (clipped to its bounds): start points of restart attempts. Played in ``problem``'s DMP,
    with its goal velocity and acceleration, such a point is a hybrid, not the other movement (:func:`family_run`
    starts from the movements themselves)."""
    rows = []
    for p in others:
        if p.n_params != problem.n_params:
            raise RefinementError(f"restart point with {p.n_params} parameters for a problem with {problem.n_params}")
        rows.append(problem.scaling.to_x(p.scaling.theta0))
    return np.array(rows, dtype=float).reshape(-1, problem.n_params)


def scout_start_points(problems: Sequence[RefinementProblem], ranking: Sequence[tuple[int, RewardBreakdown]],
                       n: int | None = None) -> np.ndarray | None:
    """Start points of the scouts (``refine(starts=...)``): the ``n`` best imitated movements of ``ranking`` (from
    :func:`rank_starts`; default :data:`DEFAULT_SCOUT_STARTS`) in the normalised space of the best one, the best first;
    None when ``n`` is 1 (every scout from the start point). A movement that failed in simulation is not a start point."""
    return scout_points(problems, simulated_order(ranking), n)


def run_start_order(order: Sequence[int], run: int, n: int | None = None) -> list[int]:
    """The start order of run ``run`` where independent runs scout from different start points (``run_starts="diverse"``):
    ``order`` (indices of the imitated movements, best first) rotated by ``run * n`` (``n``: the scouts' start points,
    default :data:`DEFAULT_SCOUT_STARTS`), so run 0 scouts from the ``n`` best, run 1 from the next ``n``, and so on,
    wrapping around when the movements run out. Why: a run's fate is mostly set by the family of movements its scouts
    settle in, so a second run from the same start points tends to end where the first did (measured on the default
    task: its REFINEMENT.md)."""
    order = list(order)
    if not order:
        raise RefinementError("no imitated movement to start from")
    shift = (int(run) * scout_starts_checked(n)) % len(order)
    return order[shift:] + order[:shift]


def run_start(problems: Sequence[RefinementProblem], order: Sequence[int], group: int, n: int | None = None) -> tuple[int, np.ndarray | None]:
    """A run's start movement (index into ``problems``) and its scouts' start points (:func:`scout_points`) from start
    group ``group`` of ``order`` (:func:`run_start_order`: 0 the best ``n``, 1 the next ``n``, ...)."""
    order = run_start_order(order, group, n)
    return order[0], scout_points(problems, order, n)


def race_points(problems: Sequence[RefinementProblem], order: Sequence[int], group: int, races: int,
                n: int | None = None) -> np.ndarray | None:
    """Start points of the further races of a run that starts from group ``group`` (:func:`run_start`): the imitated
    movements of the next ``races - 1`` groups of ``n`` in that run's normalised space, shape ``((races - 1) n,
    n_params)`` (wrapping around the movements; :func:`refine`'s ``next_starts``); None for a single race, or where the
    movements do not fill a second group."""
    n = scout_starts_checked(n)
    order = run_start_order(order, group, n)
    later = _race_members(order, races, n)
    return restart_points(problems[order[0]], [problems[i] for i in later]) if later else None


def _race_members(order: list[int], races: int, n: int) -> list[int]:
    """The movements the further races of a run with start order ``order`` (:func:`run_start_order`) start from: the
    next ``races - 1`` groups of ``n``, wrapping around; none for a single race, one scout, or too few movements."""
    if int(races) != races or races < 1:
        raise RefinementError(f"races must be an integer >= 1, got {races!r}")
    if races == 1 or n == 1 or len(order) <= n:
        return []
    return [order[(n + i) % len(order)] for i in range((int(races) - 1) * n)]


@dataclass
class RunStart:
    """Where a run starts (:func:`family_run`): its first imitated movement (index into the problems), the run's problem
    over every movement its scouts and races start from (:meth:`RefinementProblem.with_families`), its scouts' start
    points (None: one start point) and its later races' (None: one race)."""

    index: int
    problem: RefinementProblem
    starts: np.ndarray | None
    next_starts: np.ndarray | None


def hybrid_run(problems: Sequence[RefinementProblem], order: Sequence[int], group: int, races: int = 1,
               n: int | None = None) -> RunStart:
    """:func:`run_start` and :func:`race_points` as a :class:`RunStart`: the start movement's own problem, its scouts'
    and races' start points the other movements' parameters in its space (hybrids, :func:`restart_points`; the search
    of one movement, e.g. without scouts, and ``--hybrid-starts``)."""
    index, starts = run_start(problems, order, group, n)
    return RunStart(index, problems[index], starts, race_points(problems, order, group, races, n))


def family_run(problems: Sequence[RefinementProblem], order: Sequence[int], group: int, races: int = 1,
               n: int | None = None) -> RunStart:
    """:func:`run_start` and :func:`race_points` with each start point the imitated movement itself: the run's problem
    holds every movement its scouts and races start from as a family (goal velocity and acceleration, and weights
    bounded around its own), and each start point names its family. Why: with :func:`restart_points` another movement
    is its theta played with the first movement's goal velocity and acceleration, its weights clipped to the first's
    bounds; on the default task those hybrids land a median 0.25 m and up to 1.5 m from where the movements themselves do
    (REFINEMENT.md)."""
    n = scout_starts_checked(n)
    order = run_start_order(order, group, n)
    scouts = order[:n] if n > 1 else []
    later = _race_members(order, races, n)
    members = list(dict.fromkeys([order[0], *scouts, *later]))
    problem = problems[order[0]].with_families([problems[i] for i in members[1:]])

    def points(indices: list[int]) -> np.ndarray | None:
        rows = [problem.family_start(members.index(i), problems[i]) for i in indices]
        return np.array(rows, dtype=float) if rows else None

    return RunStart(order[0], problem, points(scouts), points(later))


def scout_starts_checked(n: int | None) -> int:
    """The number of scout start points, :data:`DEFAULT_SCOUT_STARTS` where None; :class:`RefinementError` unless >= 1."""
    n = DEFAULT_SCOUT_STARTS if n is None else n
    if int(n) != n or n < 1:
        raise RefinementError(f"scout starts must be an integer >= 1, got {n!r}")
    return int(n)


def scout_points(problems: Sequence[RefinementProblem], order: Sequence[int], n: int | None = None) -> np.ndarray | None:
    """:func:`scout_start_points` from ``order``: the indices of the imitated movements that could be simulated, best
    first (as ``besdrake refine`` keeps them in its start.json)."""
    n = scout_starts_checked(n)
    if n == 1:
        return None
    return restart_points(problems[order[0]], [problems[i] for i in order[:n]])
