"""The throwing task's scene: the ball (resting in the robot's scoop) and the floor, added to the simulation's
Diagram (:func:`besdrake.sim.diagram.build_diagram`) from the scenario's ``models: ball, ground``."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from besdrake.sim.diagram import parse_model, require_models
from besdrake.sim.scenario import Scenario, ScenarioError


@dataclass
class ThrowSceneHandles:
    """The bodies, frames and geometry ids a throw's rollout and effects look up (``SimHandles.scene``)."""

    ball_instance: Any
    ball_body: Any
    scoop_frame: Any
    scoop_body: Any
    ball_collision_id: Any
    ball_geometry_ids: list
    scoop_collision_ids: list
    nominal_ball_radius: float


class ThrowScene:
    """Adds the ball and the floor; on the built Diagram filters the floor's contacts and finds the ball and scoop."""

    def __init__(self) -> None:
        self.scenario: Scenario | None = None
        self.ball_instance = self.ground = None

    def add_models(self, plant, parser, scenario: Scenario) -> None:
        require_models(scenario, ("ball", "ground"))
        self.scenario = scenario
        self.ball_instance = parse_model(parser, scenario, "ball")[0]
        _require_names(plant, scenario, self.ball_instance)
        self.ground = parse_model(parser, scenario, "ground")[0]  # a <static> model: welded to the world by the parser

    def finish(self, plant, scene_graph, arm) -> ThrowSceneHandles:
        _filter_ground(plant, scene_graph, self.ground)
        inspector = scene_graph.model_inspector()
        ball_body, ball_coll, ball_ids = _ball_geometry(plant, inspector, self.ball_instance)
        scoop_body = plant.GetBodyByName(self.scenario.robot.end_effector.body, arm)
        return ThrowSceneHandles(
            ball_instance=self.ball_instance,
            ball_body=ball_body,
            scoop_frame=scoop_body.body_frame(),
            scoop_body=scoop_body,
            ball_collision_id=ball_coll[0],
            ball_geometry_ids=ball_ids,
            scoop_collision_ids=list(plant.GetCollisionGeometriesForBody(scoop_body)),
            nominal_ball_radius=float(inspector.GetShape(ball_coll[0]).radius()),
        )


def _require_names(plant, scenario: Scenario, ball) -> None:
    """:class:`ScenarioError` naming the model file when a body the throwing simulation looks up by name is
    missing (e.g. an SDF whose ball body is not called ``ball``; the robot file's names are checked when it is read)."""
    if not plant.HasBodyNamed("ball", ball):
        raise ScenarioError(f"the ball model {scenario.models.get('ball')} has no body named 'ball' (the simulation looks it up by name)")


def _filter_ground(plant, scene_graph, ground) -> None:
    """The floor is handled by the rollout (it stops when the ball reaches the floor and computes the touchdown
    analytically), so no contact with it is ever needed: filtering it saves ~15% per step."""
    from pydrake.geometry import CollisionFilterDeclaration, GeometrySet, Role

    ground_geoms = GeometrySet([g for b in plant.GetBodyIndices(ground) for g in plant.GetCollisionGeometriesForBody(plant.get_body(b))])
    all_geoms = GeometrySet(list(scene_graph.model_inspector().GetAllGeometryIds(Role.kProximity)))
    scene_graph.collision_filter_manager().Apply(CollisionFilterDeclaration().ExcludeBetween(ground_geoms, all_geoms))


def _ball_geometry(plant, inspector, ball_instance):
    """The ball's body, its one sphere collision geometry and all its sphere geometries; ScenarioError otherwise."""
    from pydrake.geometry import Sphere

    ball_body = plant.GetBodyByName("ball", ball_instance)
    ball_coll = list(plant.GetCollisionGeometriesForBody(ball_body))
    if len(ball_coll) != 1 or not isinstance(inspector.GetShape(ball_coll[0]), Sphere):
        raise ScenarioError("the ball model must have exactly one sphere collision geometry")
    ball_ids = [g for g in inspector.GetGeometries(plant.GetBodyFrameIdOrThrow(ball_body.index())) if isinstance(inspector.GetShape(g), Sphere)]
    return ball_body, ball_coll, ball_ids
