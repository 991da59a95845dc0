"""Refinement's settings: units of the normalised parameter space, the search's defaults (measured: see the
package docstring of :mod:`besdrake.search.refinement`), file names, and :class:`RefinementError`."""

from __future__ import annotations

from typing import Any

from besdrake.search.reward import SUCCESS_DISTANCE, RefinementError  # noqa: F401 - part of the settings

#: Minimum execution time (s) of a movement (the paper's), maximum: our sane choice.
MIN_EXECUTION_TIME = 0.95
MAX_EXECUTION_TIME = 4.0
#: Units of the normalised space (see :class:`~besdrake.search.refinement.scaling.ParameterScaling`).
POSITION_UNIT = 0.3  # rad
TIME_UNIT = 0.3  # s
ACCELERATION_UNIT = 2.0  # rad/s^2 at a basis centre
WEIGHT_BOUND_UNITS = 50.0
#: Population size and budget of the paper's refinement runs.
PAPER_POPSIZE = 20
PAPER_MAX_EPISODES = 10_000
#: Our default population: 10. Measured on synthetic subjects 0, 1, 2 (seed 0, 1000-1500 episodes, shared
#: CPU): population 10 reached 0.05 / 0.16 / 0.41 m, population 20 0.51 / 0.31 / 0.51 m (more generations
#: for the same number of episodes matter more here than a larger sample per generation).
DEFAULT_POPSIZE = 10
#: Initial CMA-ES step (normalised units) of the scouts and the large restarts; the small restarts draw
#: ``DEFAULT_SIGMA0 * 10**(-2u)``. Session 20 measured that with 1.0 the population stays 0.7-0.9 units wide for 20-40
#: generations (step-size adaptation in 49 dimensions is slow) and failed runs climb in rare jumps. 0.4 on all ten learn
#: runs (subjects 0-4, seeds 0 and 1; sessions 20-21), episodes to 0.1 m for 1.0 / 0.4: 491 / 420, fail / 335,
#: 708 / 510, fail / fail, 190 / 247, 177 / 248, 311 / 419, 268 / 302, fail / fail, 632 / fail: 7 of 10 reach it either
#: way, median 561.5 / 419.5, 0.4 better on 3 runs and worse on 5: within the seeds' scatter, so the default stays 1.0
#: (``--sigma0`` in the bench and ``besdrake refine``).
DEFAULT_SIGMA0 = 1.0
#: Plan sampling step (s) for the DMP rollout that the simulation executes.
PLAN_DT = 0.01
#: A restart attempt (``refine(stagnation_generations=...)``) stalls when its best reward improved by less than this (m).
STAGNATION_TOL = 0.02
#: Default search of :func:`refine` (see the package docstring for the measurements): ``cma`` options and the
#: stagnation restarts (generations; 0: none). ``refine(cma_options={}, stagnation_generations=0)`` is plain CMA-ES.
DEFAULT_CMA_OPTIONS: dict[str, Any] = {"CMA_diagonal": True, "CMA_elitist": True}
DEFAULT_STAGNATION_GENERATIONS = 10
#: Restart regimes of the stagnation restarts (:class:`~besdrake.search.cmaes.StagnationRestartCMAES`'s ``regimes``):
#: ``"large"`` (every restart with the initial step; the default before) or ``"bipop"`` (small local restarts from the
#: best candidate alternate with large ones; 16 of 20 benchmark runs against 14 of 20, see the package docstring) or ``"local"`` (small
#: restarts unless stuck: 1 of 6 hard cases against BIPOP's 2 of 6, not the default), and the population growth of the
#: large restarts (1: none; IPOP-like 2: 16 of 20 runs, pooled median 720 episodes, the same as without; package docstring).
RESTART_REGIMES = ("large", "bipop", "local")
DEFAULT_RESTART_REGIMES = "bipop"
DEFAULT_POPSIZE_GROWTH = 1.0
#: ``"local"`` regimes: small restarts in a row that did not improve the best candidate by :data:`STAGNATION_TOL` before a large one.
DEFAULT_PATIENCE = 2
#: Scouting (:class:`~besdrake.search.cmaes.StagnationRestartCMAES`'s ``scouts``): the first attempts are this many
#: independent short CMA-ES runs; the best goes on. Four, from the four best imitated movements
#: (:data:`DEFAULT_SCOUT_STARTS`), with retiming and the task reward's limit offset (see "Scouting across
#: ... families" in the package docstring), raced by successive halving (:data:`DEFAULT_SCOUT_HALVING`) in rungs of
#: :data:`DEFAULT_SCOUT_GENERATIONS` generations: 180 episodes of scouting instead of 480 (see "Racing the scouts" and
#: "Shorter rungs of the race" in the default task's REFINEMENT.md).
DEFAULT_SCOUTS = 4
#: Generations of a rung of the race (of each scout without :data:`DEFAULT_SCOUT_HALVING`; 12 in session 6, 4 until
#: session 34: on the default task's 40 benchmark runs the same 32 reach the goal within 1,000 episodes, median
#: 270 episodes instead of 420.5).
DEFAULT_SCOUT_GENERATIONS = 3
#: Where the scouts start (:func:`scout_start_points`): scout ``k`` from the ``(k mod N)``-th best imitated movement; 1:
#: every scout from the start point.
DEFAULT_SCOUT_STARTS = 4
#: Race the scouts by successive halving (rungs of :data:`DEFAULT_SCOUT_GENERATIONS`; see
#: :class:`~besdrake.search.cmaes.StagnationRestartCMAES`) instead of running each to the end one after the other.
DEFAULT_SCOUT_HALVING = True
#: The search before issue 5 (plain CMA-ES, no restarts): keyword arguments of :func:`refine`.
PLAIN_SEARCH: dict[str, Any] = {"cma_options": {}, "stagnation_generations": 0}
#: Offset (rad) of the whole movement per unit of the meta-parameter stage (:func:`meta_basis`).
META_OFFSET_UNIT = 1.0

#: Retiming (``RefinementProblem(retime=True)``): at most this many stretches (each checked), each stretching by the
#: measured peak ratio times ``1 + RETIME_MARGIN`` (the DMP's goal velocity makes a stretch only nearly uniform).
RETIME_ROUNDS = 4
#: Whether a :class:`RefinementProblem` retimes its candidates unless told (``retime=``).
DEFAULT_RETIME = True
RETIME_MARGIN = 0.002

DETAILS_FILE = "details.csv"
PROBLEM_FILE = "problem.json"
