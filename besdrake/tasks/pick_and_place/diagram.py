"""Build the pick-and-place Diagram from a :class:`~besdrake.sim.scenario.Scenario` (``diagrams/pick_and_place.yaml``).

Wiring::

    TrajectorySource "arm_plan" (q, qd of the arm) ----\\
                                                        Multiplexer -> MatrixGain (actuator order) -> plant.<robot>_desired_state
    TrajectorySource "gripper_command" (q, qd) --------/
    TrajectorySource "gravity_feedforward" (actuator torques / forces) --> plant.<robot>_actuation
    MultibodyPlant <--> SceneGraph
    plant.state --> VectorLogSink "state_logger" (every ``log_period`` s)

* **Controller**: the plant's joint PD servos on every actuator (arm and gripper; gains from the scenario / robot
  file), integrated implicitly by SAP; the effort limits saturate them, so the gripper squeezes an object with
  its effort limit (its grip force). The servos get the model's gravity torques along the plan as feed-forward
  (the rollout fills "gravity_feedforward" per plan), as an iiwa's or a Panda's controller compensates its own
  gravity: the arm tracks the plan without sagging.
* **Scene**: the scenario's ``fixtures`` model (static: shelf, table, floor; frames ``box_start`` and
  ``place_target``) and its ``box`` model (a free body held by friction only: nothing welds it to the gripper).
* The robot's base link is welded to the world at the scenario's base pose.
* Collisions within the robot are filtered out (the plan's IK keeps the arm's links apart); everything else
  collides (arm-fixture contacts are what the rollout flags).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from besdrake.sim.scenario import Scenario, ScenarioError, load_scenario, resolve_model_uri

#: Models the scenario must name.
REQUIRED_MODELS = ("fixtures", "box")


@dataclass
class PickPlaceHandles:
    """The built Diagram and what a rollout needs of it."""

    scenario: Scenario
    diagram: Any
    plant: Any
    scene_graph: Any
    arm_source: Any
    gripper_source: Any
    feedforward_source: Any
    state_logger: Any
    robot_instance: Any
    box_body: Any
    tool_frame: Any
    box_start: Any          # RigidTransform: world pose of the fixtures' box_start frame
    place_target: Any       # RigidTransform: world pose of the fixtures' place_target frame
    box_half_size: np.ndarray
    robot_geometries: list
    fixture_geometries: list
    box_geometries: list
    gripper_joint_q: np.ndarray   # indices of the gripper joints in the plant's positions
    coupled_q: np.ndarray         # indices of the joints coupled 1:1 to the first gripper joint
    arm_q: np.ndarray             # indices of the arm joints in the plant's positions
    arm_v: np.ndarray
    arm_rows: np.ndarray          # rows of the arm's actuators in the model instance's actuation vector
    visualizer: Any = None        # the MeshcatVisualizer (a Diagram built with meshcat), for replays


def _parse(parser, scenario: Scenario, key: str):
    path = resolve_model_uri(scenario.models[key])
    try:
        return parser.AddModels(str(path))[0]
    except RuntimeError as err:
        raise ScenarioError(f"model file for {key!r} ({path}) could not be parsed: {err}") from err


def _actuator_rows(plant, instance, robot) -> np.ndarray:
    """Row of each arm then gripper joint's actuator in ``instance``'s actuation vector (actuator-index order)."""
    joints = list(robot.joint_names) + list(robot.end_effector.gripper.joints)
    index = [int(plant.GetJointActuatorByName(robot.actuator_name(j), instance).index()) for j in joints]
    if len(index) != plant.num_actuators(instance):
        raise ScenarioError(f"robot {robot.name!r}: the model has actuators for joints the robot file does not name")
    rank = {idx: i for i, idx in enumerate(sorted(index))}
    return np.array([rank[i] for i in index])


def _desired_state_gain(rows: np.ndarray, n_arm: int) -> np.ndarray:
    """Matrix from [q_arm, v_arm, q_gripper, v_gripper] to a desired-state port (positions then velocities of the
    actuated joints, in the actuator ``rows`` order)."""
    n, na = len(rows), n_arm
    gain = np.zeros((2 * n, 2 * n))
    for k, row in enumerate(rows):
        col_q, col_v = (k, na + k) if k < na else (2 * na + (k - na), 2 * na + (n - na) + (k - na))
        gain[row, col_q] = 1.0
        gain[n + row, col_v] = 1.0
    return gain


def _geometries(plant, instance) -> list:
    return [g for b in plant.GetBodyIndices(instance) for g in plant.GetCollisionGeometriesForBody(plant.get_body(b))]


def _box_half_size(plant, scene_graph, box_body) -> np.ndarray:
    from pydrake.geometry import Box

    inspector = scene_graph.model_inspector()
    boxes = [inspector.GetShape(g) for g in plant.GetCollisionGeometriesForBody(box_body) if isinstance(inspector.GetShape(g), Box)]
    if not boxes:
        raise ScenarioError("the box model needs a box collision geometry (its size is the box's)")
    return 0.5 * np.array([boxes[0].width(), boxes[0].depth(), boxes[0].height()])


def _add_controllers(plant, instance, scenario: Scenario) -> None:
    from pydrake.multibody.tree import PdControllerGains

    robot = scenario.robot
    g = robot.end_effector.gripper
    for i, name in enumerate(robot.joint_names):
        act = plant.GetJointActuatorByName(robot.actuator_name(name), instance)
        act.set_controller_gains(PdControllerGains(p=scenario.controller.kp[i], d=scenario.controller.kd[i]))
    for i, name in enumerate(g.joints):
        act = plant.GetJointActuatorByName(robot.actuator_name(name), instance)
        act.set_controller_gains(PdControllerGains(p=float(g.kp[i]), d=float(g.kd[i])))


def _check(scenario: Scenario) -> None:
    robot = scenario.robot
    if robot.end_effector.gripper is None:
        raise ScenarioError(f"pick-and-place needs a robot with a gripper; {robot.name!r} has a {robot.end_effector.type!r} end effector")
    missing = [k for k in REQUIRED_MODELS if k not in scenario.models]
    if missing:
        raise ScenarioError(f"scenario {scenario.name!r}: models section is missing {missing[0]!r}")


def _add_plant(builder, scenario: Scenario):
    """Plant and SceneGraph with the robot (welded at the base pose, servo gains set), the fixtures and the box."""
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig

    from besdrake.sim.diagram import base_transform

    robot = scenario.robot
    config = MultibodyPlantConfig(time_step=scenario.time_step, discrete_contact_approximation=scenario.contact_approximation, contact_model="point")
    plant, scene_graph = AddMultibodyPlant(config, builder)
    plant.set_name("plant")
    parser = Parser(plant)
    try:
        instance = robot.add_model(plant, parser)
    except RuntimeError as err:
        raise ScenarioError(f"robot model {robot.model} could not be parsed: {err}") from err
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName(robot.base_link, instance), base_transform(scenario))
    fixtures = _parse(parser, scenario, "fixtures")
    box = _parse(parser, scenario, "box")
    _add_controllers(plant, instance, scenario)
    plant.Finalize()
    return plant, scene_graph, instance, fixtures, box


def _add_sources(builder, plant, instance, robot):
    """The arm plan's and the gripper command's TrajectorySources (reordered into the desired-state port) and the
    gravity feed-forward's (into the actuation port); placeholders until a rollout swaps its trajectories in."""
    from pydrake.systems.primitives import MatrixGain, Multiplexer, TrajectorySource
    from pydrake.trajectories import PiecewisePolynomial

    na, ng = robot.n_joints, len(robot.end_effector.gripper.joints)
    sources = []
    for name, n in (("arm_plan", na), ("gripper_command", ng)):
        src = builder.AddSystem(TrajectorySource(PiecewisePolynomial(np.zeros((n, 1))), output_derivative_order=1))
        src.set_name(name)
        sources.append(src)
    mux = builder.AddSystem(Multiplexer([2 * na, 2 * ng]))
    rows = _actuator_rows(plant, instance, robot)
    order = builder.AddSystem(MatrixGain(_desired_state_gain(rows, na)))
    for i, src in enumerate(sources):
        builder.Connect(src.get_output_port(), mux.get_input_port(i))
    builder.Connect(mux.get_output_port(), order.get_input_port())
    builder.Connect(order.get_output_port(), plant.get_desired_state_input_port(instance))
    feedforward = builder.AddSystem(TrajectorySource(PiecewisePolynomial(np.zeros((len(rows), 1)))))
    feedforward.set_name("gravity_feedforward")
    builder.Connect(feedforward.get_output_port(), plant.get_actuation_input_port(instance))
    return sources[0], sources[1], feedforward, rows


def _frames(plant, fixtures):
    ctx = plant.CreateDefaultContext()
    try:
        return tuple(plant.GetFrameByName(name, fixtures).CalcPoseInWorld(ctx) for name in ("box_start", "place_target"))
    except RuntimeError as err:
        raise ScenarioError(f"the fixtures model needs frames 'box_start' and 'place_target': {err}") from err


def build_pick_place_diagram(scenario: Scenario | str = "pick_and_place", meshcat=None, log_period: float = 0.01) -> PickPlaceHandles:
    """Build the Diagram for ``scenario`` (a Scenario or a name/path); optionally visualised in ``meshcat``."""
    from pydrake.geometry import CollisionFilterDeclaration, GeometrySet, MeshcatVisualizer, MeshcatVisualizerParams, Role
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import LogVectorOutput

    scenario = load_scenario(scenario) if not isinstance(scenario, Scenario) else scenario
    _check(scenario)
    robot = scenario.robot
    builder = DiagramBuilder()
    plant, scene_graph, instance, fixtures, box = _add_plant(builder, scenario)
    arm_source, grip_source, feedforward, rows = _add_sources(builder, plant, instance, robot)
    logger = LogVectorOutput(plant.get_state_output_port(), builder, log_period)
    logger.set_name("state_logger")
    visualizer = None if meshcat is None else MeshcatVisualizer.AddToBuilder(
        builder, scene_graph, meshcat, MeshcatVisualizerParams(role=Role.kIllustration))
    diagram = builder.Build()
    diagram.set_name(f"besdrake_{scenario.name}")

    robot_geoms = _geometries(plant, instance)
    scene_graph.collision_filter_manager().Apply(CollisionFilterDeclaration().ExcludeWithin(GeometrySet(robot_geoms)))
    box_body = plant.GetBodyByName("box", box)
    box_start, place_target = _frames(plant, fixtures)
    q_index = lambda j: plant.GetJointByName(j, instance).position_start()  # noqa: E731
    g = robot.end_effector.gripper
    return PickPlaceHandles(
        scenario=scenario, diagram=diagram, plant=plant, scene_graph=scene_graph,
        arm_source=arm_source, gripper_source=grip_source, feedforward_source=feedforward, state_logger=logger, robot_instance=instance,
        box_body=box_body, tool_frame=plant.GetFrameByName(robot.tool_frame, instance),
        box_start=box_start, place_target=place_target,
        box_half_size=_box_half_size(plant, scene_graph, box_body),
        robot_geometries=robot_geoms, fixture_geometries=_geometries(plant, fixtures), box_geometries=_geometries(plant, box),
        gripper_joint_q=np.array([q_index(j) for j in g.joints]),
        coupled_q=np.array([q_index(j) for j in g.coupled], dtype=int),
        arm_q=np.array([q_index(j) for j in robot.joint_names]),
        arm_v=np.array([plant.GetJointByName(j, instance).velocity_start() for j in robot.joint_names]),
        arm_rows=rows[:robot.n_joints], visualizer=visualizer,
    )
