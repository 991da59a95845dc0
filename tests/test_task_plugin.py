"""A task added with one module loaded as a plugin runs through the same executors as throwing."""

from __future__ import annotations

import numpy as np
import yaml

from besdrake.plan import MotionPlan
from besdrake.plugins import load_plugin
from besdrake.sim import make_executor
from besdrake.sim.scenario import DIAGRAMS_DIR, scenario_from_dict

REACH_PLUGIN = '''
from dataclasses import dataclass, field

import numpy as np

from besdrake.task import Task, register_task


@dataclass
class ReachOutcome:
    tool_end: np.ndarray | None = None
    flags: dict = field(default_factory=dict)
    message: str = ""


class ReachRollout:
    """Kinematic 'rollout': where the robot's tool ends up at the end of the plan (no dynamics)."""

    def __init__(self, scenario):
        from pydrake.multibody.plant import MultibodyPlant

        self.scenario = scenario
        self.plant = MultibodyPlant(0.0)
        scenario.robot.add_model(self.plant)
        self.plant.WeldFrames(self.plant.world_frame(), self.plant.GetFrameByName(scenario.robot.base_link))
        self.plant.Finalize()
        self.context = self.plant.CreateDefaultContext()

    def rollout(self, plan, effects=None, limits="flag"):
        if plan.duration > 5.0:
            raise ValueError("this toy task takes plans of at most 5 s")
        self.plant.SetPositions(self.context, plan.q[-1])
        tool = self.plant.GetFrameByName(self.scenario.robot.tool_frame)
        p = self.plant.CalcRelativeTransform(self.context, self.plant.world_frame(), tool).translation()
        return ReachOutcome(tool_end=p)


@register_task
class Reach(Task):
    name = "reach_test"
    description = "move the tool to a point"
    default_scenario = "reach.yaml"

    def make_rollout(self, scenario, meshcat=None):
        return ReachRollout(scenario)

    def failed_outcome(self, message):
        return ReachOutcome(flags={"sim_failed": True}, message=message)
'''


def test_a_task_plugin_runs_in_the_executors_without_code_changes(tmp_path):
    plugin = tmp_path / "reach_task.py"
    plugin.write_text(REACH_PLUGIN)
    load_plugin(plugin)
    data = yaml.safe_load((DIAGRAMS_DIR / "nominal.yaml").read_text())
    data.update(task="reach_test", models={}, name="reach")
    scenario = scenario_from_dict(data)
    up = MotionPlan(t=[0.0, 1.0], q=np.zeros((2, 6)))
    long = MotionPlan(t=[0.0, 6.0], q=np.zeros((2, 6)))  # the rollout raises: the task's failed outcome comes back
    with make_executor("serial", scenario=scenario) as ex:
        ok, failed = ex.evaluate([up, long])
    assert np.allclose(ok.tool_end, [0.0, 0.0, 1.174], atol=1e-9)  # COMPI's tool straight up
    assert failed.flags == {"sim_failed": True} and "at most 5 s" in failed.message
