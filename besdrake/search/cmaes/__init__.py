"""CMA-ES (Hansen & Ostermeier 2001) through the ``cma`` package, behind the ask/tell interface.

* Maximises: rewards are negated before they reach ``cma`` (which minimises).
* Randomness: ``cma`` draws its standard-normal samples through its ``randn`` option, which this
  wrapper points at the ``numpy.random.Generator`` given at construction (``cma``'s own ``seed``
  option is set to "do nothing", so the global ``numpy.random`` state is never touched). The
  Generator's state is therefore the whole random state of a run.
* Bounds: ``cma``'s ``bounds`` option (its default boundary handling, a smooth transformation into
  the box), so every candidate lies inside the bounds.
* Restarts: optional IPOP or BIPOP restarts (Hansen 2009, "Benchmarking a BI-population CMA-ES on
  the BBOB-2009 function testbed"), scheduled by this wrapper, not by ``cma.fmin``. When a run
  stops (``cma``'s termination criteria), the next run starts again from ``x0``:

  - *large regime* (IPOP): population ``popsize0 * 2**k`` after ``k`` large restarts, step size
    ``sigma0``;
  - *small regime* (BIPOP only): population ``floor(popsize0 * (popsize_large / (2 popsize0))**(u**2))``
    and step size ``sigma0 * 10**(-2 u)`` with ``u ~ U(0, 1)``, where ``popsize_large`` is the
    population of the last large run;
  - BIPOP picks the small regime whenever the evaluations spent in small runs are fewer than those
    spent in large runs (the first run counts as large), the large regime otherwise.

* Save/resume without pickle: :meth:`CMAES.state_dict` stores the distribution (mean, step size,
  covariance ``C`` and its eigendecomposition ``B``, ``D``), the evolution paths ``pc`` and ``ps``,
  the iteration/evaluation/eigendecomposition counters, the fitness histories that ``cma``'s
  termination criteria read, the restart bookkeeping and the Generator state. A resumed optimizer
  asks exactly the same candidates as the uninterrupted one (tested). What is approximate: the
  internal record of ``cma``'s ``tolstagnation``/``tolxstagnation`` checks and its logger are
  rebuilt from the saved histories, so a resumed run may stop at a slightly different generation
  than an uninterrupted one would.

Modules: :mod:`~besdrake.search.cmaes.core` (:class:`CMAES`), :mod:`~besdrake.search.cmaes.staged`
(:class:`StagedCMAES`), :mod:`~besdrake.search.cmaes.restarts` (:class:`StagnationRestartCMAES`),
:mod:`~besdrake.search.cmaes.state` (saving the ``cma`` strategy).
"""

from besdrake.search.cmaes.core import _RESTART_STRATEGIES, CMAES, _Run
from besdrake.search.cmaes.restarts import _STAGNATION_REGIMES, RaceStall, StagnationRestartCMAES
from besdrake.search.cmaes.staged import StagedCMAES
from besdrake.search.cmaes.state import _ARRAY_ATTRS, _LIST_ATTRS, _SCALAR_ATTRS, _get, _has, _set

__all__ = ["CMAES", "RaceStall", "StagedCMAES", "StagnationRestartCMAES"]
