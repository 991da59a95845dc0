"""The search of refinement: CMA-ES on the normalised space (:func:`make_optimizer`), with stagnation restarts and
scouts (:class:`~besdrake.search.cmaes.StagnationRestartCMAES`) or a meta-parameter stage first (:func:`meta_basis`,
:class:`~besdrake.search.cmaes.StagedCMAES`); the defaults where a setting is None."""

from __future__ import annotations

from typing import Any

import numpy as np

from besdrake.search.refinement.problem import RefinementProblem
from besdrake.search.refinement.settings import (DEFAULT_CMA_OPTIONS, DEFAULT_PATIENCE, DEFAULT_POPSIZE, DEFAULT_POPSIZE_GROWTH,
                                                 DEFAULT_RESTART_REGIMES, DEFAULT_SCOUT_GENERATIONS, DEFAULT_SCOUT_HALVING,
                                                 DEFAULT_SCOUTS, DEFAULT_SIGMA0, DEFAULT_STAGNATION_GENERATIONS, META_OFFSET_UNIT,
                                                 RESTART_REGIMES, STAGNATION_TOL, RefinementError)


def meta_basis(problem: RefinementProblem, offset_unit: float = META_OFFSET_UNIT) -> np.ndarray:
    """Directions of the meta-parameter stage in the normalised space, shape ``(n_params, 2 n + 1)``:

    * per joint, an *offset* of the whole movement (start and goal together) by ``offset_unit`` rad per
      unit: it turns the end effector (imitated movements may start with it tilted too far) and the direction of
      the movement without changing the swing's shape;
    * per joint, the *goal* (one unit of the normalised space, :data:`POSITION_UNIT` rad): the swing's amplitude;
    * the *execution time* (:data:`TIME_UNIT` s per unit).
    """
    if not (np.isfinite(offset_unit) and offset_unit > 0):
        raise RefinementError(f"offset_unit must be a finite number > 0 rad, got {offset_unit!r}")
    n = problem.parameterization.template.n_dims
    scale = problem.scaling.scale
    cols = []
    for j in range(n):
        c = np.zeros(problem.n_params)
        c[j] = offset_unit / scale[j]
        c[n + j] = offset_unit / scale[n + j]
        cols.append(c)
    for j in range(n):
        c = np.zeros(problem.n_params)
        c[n + j] = 1.0
        cols.append(c)
    c = np.zeros(problem.n_params)
    c[-1] = 1.0
    cols.append(c)
    return np.column_stack(cols)


def _search_defaults(cma_options: dict[str, Any] | None, stagnation_generations: int | None, meta_episodes: int,
                     restart_regimes: str | None = None, popsize_growth: float | None = None) -> tuple[dict[str, Any], int, str, float]:
    """The default search where a setting is None: :data:`DEFAULT_CMA_OPTIONS`, restarts after
    :data:`DEFAULT_STAGNATION_GENERATIONS` unless the meta-parameter stage is asked for (they do not combine),
    :data:`DEFAULT_RESTART_REGIMES` and :data:`DEFAULT_POPSIZE_GROWTH`."""
    cma_options = dict(DEFAULT_CMA_OPTIONS if cma_options is None else cma_options)
    if stagnation_generations is None:
        stagnation_generations = DEFAULT_STAGNATION_GENERATIONS if meta_episodes == 0 else 0
    regimes = DEFAULT_RESTART_REGIMES if restart_regimes is None else str(restart_regimes)
    if regimes not in RESTART_REGIMES:
        raise RefinementError(f"restart_regimes must be one of {RESTART_REGIMES}, got {restart_regimes!r}")
    growth = DEFAULT_POPSIZE_GROWTH if popsize_growth is None else float(popsize_growth)
    if not (np.isfinite(growth) and growth >= 1):
        raise RefinementError(f"popsize_growth must be a finite number >= 1, got {popsize_growth!r}")
    return cma_options, int(stagnation_generations), regimes, growth


def _scouting_defaults(scouts: int | None, scout_generations: int | None,
                       scout_halving: bool | None = None) -> tuple[int, int, bool]:
    """:data:`DEFAULT_SCOUTS`, :data:`DEFAULT_SCOUT_GENERATIONS` and :data:`DEFAULT_SCOUT_HALVING` where a setting is
    None, checked."""
    scouts = DEFAULT_SCOUTS if scouts is None else scouts
    scout_generations = DEFAULT_SCOUT_GENERATIONS if scout_generations is None else scout_generations
    if int(scouts) != scouts or scouts < 0 or int(scout_generations) != scout_generations or scout_generations < 1:
        raise RefinementError(f"scouts must be an integer >= 0 and scout_generations >= 1, got {scouts!r}, {scout_generations!r}")
    return int(scouts), int(scout_generations), DEFAULT_SCOUT_HALVING if scout_halving is None else bool(scout_halving)


def scouting_episodes(popsize: int = DEFAULT_POPSIZE, scouts: int | None = None, scout_generations: int | None = None,
                      scout_halving: bool | None = None) -> int:
    """Episodes the scouts take before the best goes on (none stalling early); defaults where None."""
    scouts, scout_generations, halving = _scouting_defaults(scouts, scout_generations, scout_halving)
    if scouts < 2:
        return 0
    if not halving:
        return scouts * scout_generations * int(popsize)
    total, n = 0, scouts
    while n > 1:  # a rung of n scouts, then the better half races on
        total += n * scout_generations * int(popsize)
        n = (n + 1) // 2
    return total


def make_optimizer(
    problem: RefinementProblem,
    seed: int = 0,
    sigma0: float = DEFAULT_SIGMA0,
    popsize: int = DEFAULT_POPSIZE,
    x0: np.ndarray | None = None,
    *,
    meta_episodes: int = 0,
    meta_sigma: float = 1.0,
    stagnation_generations: int | None = None,
    starts: np.ndarray | None = None,
    restart_from_best: bool = True,
    stagnation_tol: float = STAGNATION_TOL,
    max_attempt_generations: int = 0,
    cma_options: dict[str, Any] | None = None,
    popsize_growth: float | None = None,
    restart_regimes: str | None = None,
    small_share: float = 1.0,
    patience: int = DEFAULT_PATIENCE,
    scouts: int | None = None,
    scout_generations: int | None = None,
    scout_halving: bool | None = None,
    switch_distance: float | None = None,
    next_starts: np.ndarray | None = None,
    race_stall=None,
):
    """CMA-ES on the normalised space, started at the imitated movement (``x0 = 0``) unless ``x0`` is given.

    With ``stagnation_generations > 0`` a :class:`~besdrake.search.cmaes.StagnationRestartCMAES`: a
    CMA-ES attempt ends when its best reward improved by less than ``stagnation_tol`` (m) over that many
    generations (or after ``max_attempt_generations``), and the next attempt starts with a fresh step
    ``sigma0`` from the next row of ``starts`` (normalised candidates, e.g. :func:`restart_points`;
    default: ``x0`` only), or from the best candidate so far with ``restart_from_best``. ``cma_options``:
    further options of the ``cma`` package (JSON values), e.g. ``{"CMA_diagonal": True}`` (separable CMA-ES).

    With ``meta_episodes > 0`` a :class:`~besdrake.search.cmaes.StagedCMAES`: first CMA-ES (step
    ``meta_sigma``) over the meta-parameters of :func:`meta_basis` for ``meta_episodes`` episodes, then
    CMA-ES over all parameters from the best candidate so far with step ``sigma0``.

    ``switch_distance`` (m; raced scouts only): a scout that went on and ended with its best objective (minus the
    reward) above it hands over to the next scout the race eliminated (``StagnationRestartCMAES``'s ``switch_below``).
    ``next_starts`` (rows, groups of ``scouts``; needs ``switch_distance``): where the race's winner ends with the run
    still farther than the switch distance, the next group of start points is raced before any eliminated scout goes
    on (e.g. the next imitated movements: :func:`~besdrake.search.refinement.starts.race_points`). ``race_stall`` (a
    :class:`~besdrake.search.cmaes.RaceStall`; needs ``next_starts``): the next group is raced also where the current
    race stalls short of the goal."""
    from besdrake.search.cmaes import CMAES, StagedCMAES

    x0 = np.zeros(problem.n_params) if x0 is None else np.asarray(x0, dtype=float)
    bounds = problem.x_bounds
    x0 = np.clip(x0, bounds[:, 0] + 1e-9, bounds[:, 1] - 1e-9)
    rng = np.random.default_rng(seed)
    cma_options, stagnation_generations, restart_regimes, popsize_growth = _search_defaults(
        cma_options, stagnation_generations, meta_episodes, restart_regimes, popsize_growth)
    scouts, scout_generations, scout_halving = _scouting_defaults(scouts, scout_generations, scout_halving)
    if stagnation_generations > 0 and meta_episodes > 0:
        raise RefinementError("stagnation restarts and the meta-parameter stage do not combine; give one of them")
    if problem.fixed and meta_episodes > 0:
        raise RefinementError("the meta-parameter stage searches one imitated movement: a problem with families needs restarts")
    if next_starts is not None and (stagnation_generations == 0 or switch_distance is None):
        raise RefinementError("next_starts (further races) need the stagnation restarts, raced scouts and a switch_distance")
    if race_stall is not None and next_starts is None:
        raise RefinementError("race_stall (racing on when a race stalls) needs next_starts: further start points to race")
    if stagnation_generations > 0:
        from besdrake.search.cmaes import StagnationRestartCMAES

        pts = _start_points(x0, starts, bounds)
        return StagnationRestartCMAES(pts, sigma0, rng, popsize=popsize, bounds=bounds, stagnation_generations=stagnation_generations,
                                      tol=stagnation_tol, max_generations=max_attempt_generations, restart_from_best=restart_from_best,
                                      cma_options=cma_options, popsize_growth=popsize_growth, regimes=restart_regimes,
                                      small_share=small_share, patience=patience, scouts=scouts,
                                      scout_generations=scout_generations, scout_halving=scout_halving,
                                      switch_below=_switch_below(switch_distance, scouts, scout_halving),
                                      next_starts=None if next_starts is None else _start_points(x0, next_starts, bounds),
                                      race_stall=race_stall, fixed=problem.fixed)
    if meta_episodes > 0:
        return StagedCMAES(x0, meta_basis(problem), meta_sigma, sigma0, rng, subspace_evaluations=meta_episodes,
                           popsize_subspace=popsize, popsize=popsize, bounds=bounds, cma_options=cma_options)
    return CMAES(x0, sigma0, rng, popsize=popsize, bounds=bounds, cma_options=cma_options, fixed=problem.fixed)


def checked_switch_distance(switch_distance) -> float | None:
    """:func:`refine`'s ``switch_distance`` as a distance > 0 (m) or None, else :class:`RefinementError`."""
    if switch_distance is None:
        return None
    try:
        d = float(switch_distance)
    except (TypeError, ValueError):
        d = float("nan")
    if not (np.isfinite(d) and d > 0):
        raise RefinementError(f"switch_distance must be a distance > 0 (m) or None, got {switch_distance!r}")
    return d


def _switch_below(switch_distance: float | None, scouts: int, scout_halving: bool) -> float | None:
    """The reward below which a raced scout hands over to the next (None: never), checked."""
    d = checked_switch_distance(switch_distance)
    if d is None:
        return None
    if scouts < 2 or not scout_halving:
        raise RefinementError("switch_distance needs raced scouts (scouts >= 2 and scout_halving)")
    return -d


def _start_points(x0: np.ndarray, starts: np.ndarray | None, bounds: np.ndarray) -> np.ndarray:
    """The attempts' start points (rows; default ``x0`` alone), kept strictly inside ``bounds``."""
    pts = x0[None, :] if starts is None else np.atleast_2d(np.asarray(starts, dtype=float))
    if pts.shape[1:] != (x0.size,):
        raise RefinementError(f"starts must have {x0.size} columns, got shape {pts.shape}")
    span = bounds[:, 1] - bounds[:, 0]
    return np.clip(pts, bounds[:, 0] + 1e-9 * span, bounds[:, 1] - 1e-9 * span)
