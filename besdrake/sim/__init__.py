"""Simulation: a robot and its task's scene as a Drake Diagram, physical effects, rollouts and executors.

Quick start::

    from besdrake.sim import Rollout, make_executor
    from besdrake.sim.throws import default_throw

    sim = Rollout("nominal")                      # build once per process (~0.3 s)
    out = sim.rollout(default_throw(amplitude=0.35), effects={"base_offset": {"z": -0.03}})
    out.touchdown, out.release_time, out.flags    # (x, y) in m, s, {flag: bool}

    with make_executor("process", workers=2) as ex:   # "serial" | "process" | "ray"
        outcomes = ex.evaluate(plans, effects=None)    # one Outcome per plan, same on every backend

Modules: :mod:`~besdrake.sim.scenario` (YAML scenarios in ``diagrams/``), :mod:`~besdrake.sim.diagram`
(the Diagram), :mod:`~besdrake.sim.rollout` (the black box), :mod:`~besdrake.sim.flight` (free flight),
:mod:`~besdrake.sim.effects` (registry of physical effects), :mod:`~besdrake.sim.outcome`,
:mod:`~besdrake.sim.executors`, :mod:`~besdrake.sim.throws` (default throw), :mod:`~besdrake.sim.record`
(HTML replay), :mod:`~besdrake.sim.bench` (``besdrake bench rollout``).

Design choices (details in the module docstrings and ``diagrams/nominal.yaml``): arm on a 0.5 m pedestal;
a 45-degree square funnel as scoop with its lip 10 mm above the resting ball's centre; point contact
with Drake's "lagged" solver; the plant's implicit joint PD servos; a 2.5 ms step (fidelity target);
the simulation stops as soon as the ball has left the scoop for good and the flight is computed
analytically (ODE with drag).
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
