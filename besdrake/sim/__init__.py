"""Simulation: a robot and its task's scene as a Drake Diagram, physical effects, rollouts and executors.

Quick start::

    from besdrake.sim import Rollout, make_executor

    sim = Rollout("nominal")                      # the scenario's task's rollout, built once per process
    out = sim.rollout(plan, effects={"base_offset": {"z": -0.03}})   # the task's outcome

    with make_executor("process", workers=2) as ex:   # "serial" | "process" | "ray"
        outcomes = ex.evaluate(plans, effects=None)    # one outcome per plan, same on every backend

Modules: :mod:`~besdrake.sim.scenario` (YAML scenarios in ``diagrams/``), :mod:`~besdrake.sim.diagram`
(the Diagram), :mod:`~besdrake.sim.rollout` (the task's black box, see :mod:`besdrake.task`),
:mod:`~besdrake.sim.effects` (registry of physical effects), :mod:`~besdrake.sim.executors`,
:mod:`~besdrake.sim.scheduler` (independent jobs sharing one executor, their batches merged),
:mod:`~besdrake.sim.record` (HTML replay). What a task simulates and measures lives in its folder
(``besdrake/tasks/<name>/``).

Design choices (details in the module docstrings and ``diagrams/nominal.yaml``): point contact with Drake's
"lagged" solver; the plant's implicit joint PD servos; a 2.5 ms step (fidelity target).
"""

from besdrake.sim.effects import Effect, EffectError, Param, get_effect, list_effects, register_effect
from besdrake.sim.scenario import Scenario, ScenarioError, load_scenario

__all__ = [
    "Effect",
    "EffectError",
    "Param",
    "get_effect",
    "list_effects",
    "register_effect",
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
