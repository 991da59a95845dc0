"""The black box that learning loops call, for any task: ``Rollout(scenario).rollout(plan, effects, limits)``.

The simulation knows no task: :func:`Rollout` asks the scenario's task (:mod:`besdrake.task`) for its rollout
black box (``get_task(scenario.task).make_rollout(scenario)``), which executes a
:class:`~besdrake.plan.MotionPlan` and returns the task's outcome. A malformed plan raises
:class:`~besdrake.plan.PlanError`, a plan beyond the position limits :class:`~besdrake.plan.PlanLimitError`
(``limits="raise"``) or is simulated and flagged (``limits="flag"``, for learning loops exploring freely).
"""

from __future__ import annotations

from typing import Any

from besdrake.plan import PlanLimitError
from besdrake.sim.scenario import Scenario, load_scenario

__all__ = ["PlanLimitError", "Rollout", "shared_rollout"]


def Rollout(scenario: Scenario | str = "nominal", meshcat=None) -> Any:  # noqa: N802 - the old class's name
    """The rollout black box of ``scenario``'s task, one Diagram reused for many rollouts (built once per
    process): ``Rollout("nominal").rollout(plan, effects)``."""
    from besdrake.task import get_task

    scenario = load_scenario(scenario) if not isinstance(scenario, Scenario) else scenario
    return get_task(scenario.task).make_rollout(scenario, meshcat=meshcat)


_SHARED: dict[str, Any] = {}


def shared_rollout(scenario: str = "nominal") -> Any:
    """A per-process rollout for a scenario name or path, built on first use and reused afterwards."""
    key = str(scenario)
    if key not in _SHARED:
        _SHARED[key] = Rollout(scenario)
    return _SHARED[key]
