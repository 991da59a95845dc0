"""Simulation: COMPI with scoop as a Drake Diagram, physical effects, rollouts and executors.

Public API::

    from besdrake.sim import load_scenario, build_diagram, Rollout, shared_rollout, Outcome, make_executor
    from besdrake.sim import register_effect, get_effect, list_effects, Effect, Param
    from besdrake.sim.throws import default_throw
"""

from besdrake.sim.effects import Effect, EffectError, Param, get_effect, list_effects, register_effect
from besdrake.sim.outcome import Outcome
from besdrake.sim.scenario import Scenario, ScenarioError, load_scenario

__all__ = [
    "Effect",
    "EffectError",
    "Param",
    "get_effect",
    "list_effects",
    "register_effect",
    "Outcome",
    "Scenario",
    "ScenarioError",
    "load_scenario",
    "build_diagram",
    "Rollout",
    "PlanLimitError",
    "shared_rollout",
    "make_executor",
]


def __getattr__(name):  # lazy: importing pydrake-heavy modules only when used
    if name == "build_diagram":
        from besdrake.sim.diagram import build_diagram

        return build_diagram
    if name in ("Rollout", "PlanLimitError", "shared_rollout"):
        from besdrake.sim import rollout

        return getattr(rollout, name)
    if name == "make_executor":
        from besdrake.sim.executors import make_executor

        return make_executor
    raise AttributeError(name)
