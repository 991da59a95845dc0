"""Policy search: ask/tell optimizers, contextual policy search, behaviour templates.

Every optimizer maximises a reward through ``ask``/``tell`` (see :mod:`besdrake.search.base`), is
seeded with a ``numpy.random.Generator`` and saves a resumable state (JSON + npz):

* local search: :class:`CMAES` (through ``cma``), :class:`REPS`, :class:`PI2`;
* Bayesian optimization: :class:`BayesianOptimizer` (UCB, EI, entropy search, minimum regret search);
* contextual: :class:`CREPS`, :class:`BOCPS`, :class:`ACES` (active context selection);
* drivers: :func:`run_search` / :func:`run_contextual_search` write every episode to disk before the
  optimizer sees it and resume a killed run;
* refinement of a task's DMP towards its reward: :mod:`besdrake.search.refinement` (the task's reward,
  :meth:`besdrake.task.Task.reward`) and :mod:`besdrake.search.templates` (behaviour templates and the template pool).
"""

from besdrake.search.aces import ACES
from besdrake.search.base import ContextualOptimizer, Optimizer, SearchResult
from besdrake.search.bayesopt import BayesianOptimizer
from besdrake.search.bocps import BOCPS
from besdrake.search.cmaes import CMAES
from besdrake.search.creps import CREPS
from besdrake.search.gp import GaussianProcess
from besdrake.search.loop import LoopResult, batch_evaluator, run_contextual_search, run_search
from besdrake.search.pi2 import PI2
from besdrake.search.reps import REPS

__all__ = [
    "ACES",
    "BOCPS",
    "BayesianOptimizer",
    "CMAES",
    "CREPS",
    "ContextualOptimizer",
    "GaussianProcess",
    "LoopResult",
    "Optimizer",
    "PI2",
    "REPS",
    "SearchResult",
    "batch_evaluator",
    "run_contextual_search",
    "run_search",
]
