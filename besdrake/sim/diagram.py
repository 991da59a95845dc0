"""Build the simulation Diagram of a :class:`~besdrake.sim.scenario.Scenario`: the robot and its task's scene.

Wiring (render it with ``scripts/render_diagrams.py``)::

    TrajectorySource (motion plan q, qd) --> plant.<robot>_desired_state
    MultibodyPlant <--> SceneGraph
    plant.state --> VectorLogSink (the robot's and the scene's states, every time step)
    SceneGraph --> MeshcatVisualizer (optional)

The scene is the task's (:meth:`besdrake.task.Task.scene`): an object with ``add_models(plant, parser, scenario)``,
called once the robot is welded at its base and before the plant is finalised (the task's objects and fixtures, from
the scenario's ``models``; :func:`parse_model` and :func:`require_models` help), and ``finish(plant, scene_graph)``,
called on the built Diagram, whose return value (the bodies, frames and geometry ids the task's rollout needs) becomes
:attr:`SimHandles.scene`.

Design choices:

* **Controller: the plant's built-in joint PD servos** (``JointActuator`` PD gains, driven by the plant's
  desired-state port). A robot's drives are position-controlled servos, which this models directly; the
  SAP/lagged/similar solvers integrate the PD terms implicitly, so the stiff gains are stable at the
  5 ms step and cost no extra system per step (an InverseDynamicsController would need a second plant and
  a per-step inverse dynamics evaluation, and with explicit coupling would limit the step). Effort limits
  from the URDF saturate the servos. Gains live in the Context (the ``gain_scale`` effect).
* **Base pose in the Context**: the robot's base link is welded to a ``FixedOffsetFrame`` ("robot_base")
  on the world, whose pose is a Context parameter (the ``base_offset`` effect).
* **Motion plan swap without rebuild**: ``TrajectorySource.UpdateTrajectory`` (see :class:`~besdrake.sim.rollout.Rollout`).
* **Contact**: point contact, discrete solver from the scenario (``lagged`` by default: like SAP it handles
  the implicit PD gains, and it is the cheapest of the convex solvers for our few contacts).
* A grey pedestal (visual only) marks the designed base height.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from besdrake.sim.scenario import Scenario, ScenarioError, load_scenario, resolve_model_uri


@dataclass
class SimHandles:
    """The built Diagram and the handles a rollout needs (systems, bodies, frames, geometry ids)."""

    scenario: Scenario
    diagram: Any
    plant: Any
    scene_graph: Any
    plan_source: Any
    state_logger: Any
    arm: Any
    base_frame: Any
    actuators: list
    #: What the task's scene returned from ``finish`` (None without a scene).
    scene: Any = None
    visualizer: Any = None
    #: True while the actuators carry scaled gains (effect gain_scale); Rollout restores them on reset.
    gains_scaled: bool = False

    def plant_context(self, context):
        return self.plant.GetMyMutableContextFromRoot(context)

    def scene_graph_context(self, context):
        return self.scene_graph.GetMyMutableContextFromRoot(context)


def parse_model(parser, scenario: Scenario, key: str):
    """Add the scenario's model ``key`` (its ``models`` entry); :class:`ScenarioError` naming the file otherwise."""
    path = resolve_model_uri(scenario.models[key])
    if not path.is_file():
        raise ScenarioError(f"model file for {key!r} not found: {path}")
    try:
        return parser.AddModels(str(path))
    except RuntimeError as err:
        raise ScenarioError(f"model file for {key!r} ({path}) could not be parsed: {err}") from err


def require_models(scenario: Scenario, keys: tuple[str, ...]) -> None:
    """:class:`ScenarioError` naming the first of ``keys`` that the scenario's ``models`` section lacks."""
    missing = [k for k in keys if k not in scenario.models]
    if missing:
        raise ScenarioError(f"scenario {scenario.name!r}: models section is missing {missing[0]!r}")


def _add_robot(plant, parser, scenario: Scenario):
    try:
        return scenario.robot.add_model(plant, parser)
    except RuntimeError as err:
        raise ScenarioError(f"robot model {scenario.robot.model} could not be parsed: {err}") from err


def base_transform(scenario: Scenario):
    """World pose of the base frame from the scenario's base pose."""
    from pydrake.math import RigidTransform, RollPitchYaw

    b = scenario.base
    return RigidTransform(RollPitchYaw(0.0, 0.0, b.yaw), [b.x, b.y, b.z])


def build_diagram(scenario: Scenario | str = "nominal", meshcat=None, sampled_output_ports: bool = True) -> SimHandles:
    """Build the Diagram for ``scenario`` (a Scenario or a name/path) with its task's scene; optionally visualise in
    ``meshcat``. ``sampled_output_ports`` (Drake's ``MultibodyPlantConfig.use_sampled_output_ports``): True, the
    plant's output ports (contact results, reaction forces, ...) hold the values of the last step, computed at every
    step; False, they are computed only when read, from the current state (the dynamics are the same, bit for bit,
    and a step is cheaper: the reaction forces and contact results are not computed per step)."""
    from besdrake.task import get_task

    from pydrake.geometry import MeshcatVisualizer, MeshcatVisualizerParams, Role
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
    from pydrake.multibody.tree import FixedOffsetFrame
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import LogVectorOutput, TrajectorySource
    from pydrake.trajectories import PiecewisePolynomial

    scenario = load_scenario(scenario) if not isinstance(scenario, Scenario) else scenario
    builder = DiagramBuilder()
    config = MultibodyPlantConfig(
        time_step=scenario.time_step,
        discrete_contact_approximation=scenario.contact_approximation,
        contact_model="point",
        use_sampled_output_ports=sampled_output_ports,
    )
    plant, scene_graph = AddMultibodyPlant(config, builder)
    plant.set_name("plant")
    parser = Parser(plant)
    robot = scenario.robot
    scene = get_task(scenario.task).scene()
    arm = _add_robot(plant, parser, scenario)
    base_frame = plant.AddFrame(FixedOffsetFrame("robot_base", plant.world_frame(), base_transform(scenario)))
    plant.WeldFrames(base_frame, plant.GetFrameByName(robot.base_link, arm))
    if scene is not None:
        scene.add_models(plant, parser, scenario)
    _add_pedestal(plant, scenario)
    actuators = _servo_actuators(plant, arm, scenario)
    plant.Finalize()

    # Plan source; the actual plan is swapped in per rollout.
    hold = PiecewisePolynomial.FirstOrderHold([0.0, 1.0], np.zeros((robot.n_joints, 2)))
    source = builder.AddSystem(TrajectorySource(hold, output_derivative_order=1))
    source.set_name("motion_plan")
    builder.Connect(source.get_output_port(), plant.get_desired_state_input_port(arm))
    logger = LogVectorOutput(plant.get_state_output_port(), builder, scenario.time_step)
    logger.set_name("state_logger")

    visualizer = None
    if meshcat is not None:
        visualizer = MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, MeshcatVisualizerParams(role=Role.kIllustration))
    diagram = builder.Build()
    diagram.set_name(f"besdrake_{scenario.name}")

    return SimHandles(
        scenario=scenario,
        diagram=diagram,
        plant=plant,
        scene_graph=scene_graph,
        plan_source=source,
        state_logger=logger,
        arm=arm,
        base_frame=base_frame,
        actuators=actuators,
        scene=None if scene is None else scene.finish(plant, scene_graph, arm),
        visualizer=visualizer,
    )


def _add_pedestal(plant, scenario: Scenario) -> None:
    """A grey box under a base raised more than 2 cm (visual only)."""
    from pydrake.geometry import Box
    from pydrake.math import RigidTransform

    z = scenario.base.z
    if z > 0.02:
        plant.RegisterVisualGeometry(
            plant.world_body(),
            RigidTransform([scenario.base.x, scenario.base.y, z / 2 - 0.06]),
            Box(0.25, 0.25, max(z - 0.12, 0.01)),
            "pedestal",
            np.array([0.45, 0.45, 0.45, 1.0]),
        )


def _servo_actuators(plant, arm, scenario: Scenario) -> list:
    """The arm's actuators (looked up by name, robot file order) with the scenario's PD gains set."""
    from pydrake.multibody.tree import PdControllerGains

    robot, actuators = scenario.robot, []
    for i, name in enumerate(robot.joint_names):
        act = plant.GetJointActuatorByName(robot.actuator_name(name), arm)
        act.set_controller_gains(PdControllerGains(p=scenario.controller.kp[i], d=scenario.controller.kd[i]))
        actuators.append(act)
    return actuators
