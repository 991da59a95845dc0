"""Refinement in simulation: a task's policy-search problem over a template DMP's parameters (paper section 3.1.5,
step 1).

Modules: :mod:`~besdrake.search.refinement.settings` (units, defaults, :class:`RefinementError`),
:mod:`~besdrake.search.refinement.records` (:class:`RewardBreakdown`, ``details.csv``),
:mod:`~besdrake.search.refinement.scaling` (:class:`ParameterScaling`), :mod:`~besdrake.search.refinement.problem`
(:class:`RefinementProblem`), :mod:`~besdrake.search.refinement.starts` (start points of restarts and scouts),
:mod:`~besdrake.search.refinement.optimizer` (:func:`make_optimizer`), :mod:`~besdrake.search.refinement.run`
(:func:`refine`, :class:`RefinementResult`).

A movement imitated from a human (:class:`besdrake.imitation.DMP`: start and goal per joint, forcing-term weights,
execution time) rarely achieves the task on the robot. Refinement changes all of its parameters to maximise the
task's reward (:meth:`besdrake.task.Task.reward`: a callable ``reward(plan, outcome, limits) -> RewardBreakdown``,
in m, with ``penalty(plan, limits)`` for joint-limit violations, :meth:`besdrake.plan.MotionPlan.check_limits`).
A failed simulation or a parameter vector that gives no DMP rollout is a failed episode: the reward is NaN and the
search loop records it as failed (the optimizers penalise it).

* :class:`ParameterScaling` maps the optimizer's normalised space ``x`` to ``theta`` and back:
  ``theta = theta0 + scale * x``. One unit is :data:`POSITION_UNIT` rad for start/goal,
  :data:`TIME_UNIT` s for the execution time and, for each weight, the weight change that changes the
  joint's acceleration by :data:`ACCELERATION_UNIT` rad/s^2 at its basis centre. Bounds: start and goal within the
  joint position limits, execution time in [:data:`MIN_EXECUTION_TIME`, :data:`MAX_EXECUTION_TIME`] s, weights within
  +-:data:`WEIGHT_BOUND_UNITS` units of the imitated value.
* :class:`RefinementProblem` evaluates batches of normalised candidates through a rollout executor
  (:func:`besdrake.sim.make_executor`), keeps a per-episode record (outcome point, distance, penalty, flags) in
  ``details.csv`` beside the loop's ``episodes.csv``, keyed by :func:`params_key`, so a resumed run knows the
  distances of the episodes before the restart; candidates are retimed (:meth:`RefinementProblem.retimed`) to
  stay within the velocity and acceleration limits.
* :func:`refine` runs separable, elitist CMA-ES with stagnation restarts in BIPOP regimes after scouts from the best
  imitated movements raced by successive halving (:func:`make_optimizer`, :data:`DEFAULT_CMA_OPTIONS`,
  :data:`DEFAULT_SCOUTS`, :data:`DEFAULT_RESTART_REGIMES`) through the resumable search loop
  (:func:`besdrake.search.loop.run_search`). Success of a run: the first episode within :data:`SUCCESS_DISTANCE` of
  the target with no limit violated; :func:`refine` stops after that generation by default.

Why these defaults (measurements on a task, with every alternative screened):
the notes beside the task that was measured (``besdrake/tasks/<name>/REFINEMENT.md``).
"""


from besdrake.search.refinement.optimizer import make_optimizer, meta_basis, scouting_episodes
from besdrake.search.refinement.problem import RefinementProblem
from besdrake.search.refinement.records import RewardBreakdown, failed_breakdown, params_key, read_details
from besdrake.search.refinement.run import AnyStall, RefinementResult, StallRule, plot_learning_curves, race_stall_rule, refine
from besdrake.search.refinement.scaling import ParameterScaling
from besdrake.search.refinement.settings import (ACCELERATION_UNIT, DEFAULT_CMA_OPTIONS, DEFAULT_PATIENCE, DEFAULT_POPSIZE,
                                                 DEFAULT_POPSIZE_GROWTH, DEFAULT_RESTART_REGIMES, DEFAULT_RETIME,
                                                 DEFAULT_SCOUT_GENERATIONS, DEFAULT_SCOUT_HALVING, DEFAULT_SCOUT_STARTS,
                                                 DEFAULT_SCOUTS, DEFAULT_SIGMA0, DEFAULT_STAGNATION_GENERATIONS, DETAILS_FILE,
                                                 MAX_EXECUTION_TIME, META_OFFSET_UNIT, MIN_EXECUTION_TIME, PAPER_MAX_EPISODES,
                                                 PAPER_POPSIZE, PLAIN_SEARCH, PLAN_DT, POSITION_UNIT, PROBLEM_FILE,
                                                 RESTART_REGIMES, RETIME_MARGIN, RETIME_ROUNDS, STAGNATION_TOL,
                                                 SUCCESS_DISTANCE, TIME_UNIT, WEIGHT_BOUND_UNITS, RefinementError)
from besdrake.search.refinement.starts import (RunStart, best_start, family_run, hybrid_run, race_points, rank_starts, restart_points, run_start,
                                               run_start_order, scout_points, scout_start_points, scout_starts_checked, simulated_order)

__all__ = [
    "SUCCESS_DISTANCE", "DEFAULT_POPSIZE", "DEFAULT_SIGMA0", "MIN_EXECUTION_TIME", "MAX_EXECUTION_TIME", "PAPER_POPSIZE",
    "RefinementError", "RewardBreakdown", "ParameterScaling", "RefinementProblem",
    "RefinementResult", "StallRule", "AnyStall", "race_stall_rule",
    "RunStart", "family_run", "hybrid_run", "best_start", "race_points", "rank_starts", "restart_points", "run_start",
    "run_start_order", "scout_start_points", "scout_points",
    "scout_starts_checked", "simulated_order", "scouting_episodes", "make_optimizer", "refine", "read_details", "params_key",
    "failed_breakdown", "meta_basis", "plot_learning_curves",
]
