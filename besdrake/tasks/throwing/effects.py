"""The throwing task's effects: the ball (mass, radius, placement in the scoop), the scoop (friction, mounting
tilt) and the flight (air drag). Registered after the registry's robot effects (:mod:`besdrake.sim.effects`),
in this order, when the registry is first read; they act on a :class:`ThrowSetup`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from besdrake.sim.effects import Effect, EffectError, Param, RolloutSetup, get_effect, register_effect


@dataclass(kw_only=True)
class ThrowSetup(RolloutSetup):
    """A throw's rollout setup: ``ball_radius``/``ball_mass`` (m, kg): used to place the ball and in flight;
    ``drag_coefficient``/``air_density``: quadratic drag in flight; ``wind``: air velocity (m/s); ``ball_offset``:
    the ball's placement in the scoop's x/y plane (m)."""

    ball_radius: float
    ball_mass: float
    drag_coefficient: float = 0.0
    air_density: float = 1.2
    wind: np.ndarray = field(default_factory=lambda: np.zeros(3))
    ball_offset: np.ndarray = field(default_factory=lambda: np.zeros(2))


@register_effect
class AirDrag(Effect):
    """Quadratic air drag on the ball in flight: F = -1/2 rho c_d A |v| v, A = pi r^2.

    A smooth sphere has c_d ~ 0.47; a foam ball ~0.5. Nominal 0 (vacuum), as in the designed simulation.
    Applied in the flight model (ODE after release); while the ball sits in the scoop drag is negligible
    against the contact forces and is ignored. A nonzero drag shortens the throw. No rebuild.
    """

    name = "air_drag"
    applied_via = "flight"
    params = {
        "cd": Param(0.0, 0.0, 1.0, "1", "drag coefficient"),
        "rho": Param(1.2, 1.0, 1.3, "kg/m^3", "air density"),
    }

    def apply(self, setup, values):
        setup.drag_coefficient = values["cd"]
        setup.air_density = values["rho"]


@register_effect
class BallPlacement(Effect):
    """Where the ball sits in the scoop at the start: off-centre by (x, y) in the scoop's plane.

    A person puts the ball into the scoop by hand, so its start varies from throw to throw by a few
    millimetres (the virtual lab draws it per trial); a constant offset is a systematic placement
    habit. The ball rests against the 45-degree funnel walls, so moving its centre sideways by d
    lifts it by d per wall it moves towards. Off-centre balls leave the rim earlier or later and
    land noticeably elsewhere (about 1-2 cm on the floor per 2 mm). Applied where the ball is
    placed; no rebuild.
    """

    name = "ball_placement"
    applied_via = "initial state"
    params = {
        "x": Param(0.0, -0.008, 0.008, "m", "offset along the scoop frame's x axis"),
        "y": Param(0.0, -0.008, 0.008, "m", "offset along the scoop frame's y axis"),
    }

    def apply(self, setup, values):
        setup.ball_offset = np.array([values["x"], values["y"]], dtype=float)


def ball_placed(habit: dict[str, float] | None, offset) -> dict[str, float]:
    """``ball_placement`` parameters of a ball put ``offset`` (m, scoop x/y) away from ``habit`` (the systematic
    placement ``{"x": .., "y": ..}``; None: centred), clipped to the effect's bounds (where a ball can sit)."""
    bounds = get_effect("ball_placement").params
    habit = habit or {}
    return {ax: float(np.clip(habit.get(ax, 0.0) + offset[k], bounds[ax].low, bounds[ax].high)) for k, ax in enumerate(("x", "y"))}


def placement_quadrature(sd: float) -> tuple[np.ndarray, np.ndarray]:
    """Ball placements ``(K, 2)`` (m, scoop x/y, around the habit) and weights ``(K,)`` whose weighted mean stands
    for the N(0, sd^2)-per-axis scatter of the ball in the scoop: the 3 x 3 Gauss-Hermite product rule (nodes 0
    and +-sqrt(3) sd, weights 2/3 and 1/6 per axis), the centre first; exact for anything quadratic in the
    placement. ``sd == 0``: the centre alone. Used by the Transferability Approach (a plan's expected landing)
    and the diagnosis (how much a throw scatters)."""
    if sd <= 0:
        return np.zeros((1, 2)), np.ones(1)
    nodes, weights = np.array([0.0, -np.sqrt(3.0), np.sqrt(3.0)]) * sd, np.array([2.0, 0.5, 0.5]) / 3.0
    i, j = (a.ravel() for a in np.meshgrid(range(3), range(3), indexing="ij"))
    return np.column_stack([nodes[i], nodes[j]]), weights[i] * weights[j]


@register_effect
class BallProperties(Effect):
    """Ball mass and radius (a different ball). The mass and the solid-sphere inertia 2/5 m r^2 are set in the
    plant Context; the radius is changed in the SceneGraph Context (``SceneGraph.ChangeShape`` on the
    collision and visual spheres), which the contact solver reads every step. The ball is placed in the
    scoop according to its radius. The stiff servos hardly notice the ball's weight; a heavier foam ball
    is squeezed more into the funnel while the arm accelerates and springs out a little faster (it lands
    further); a larger ball sits higher in the funnel, leaves a little earlier and faster (further), and has
    more drag in flight when ``air_drag`` is on. No rebuild.
    """

    name = "ball"
    params = {
        "mass": Param(0.05, 0.02, 0.2, "kg", "ball mass"),
        "radius": Param(0.035, 0.028, 0.045, "m", "ball radius"),
    }

    def apply(self, setup, values):
        from pydrake.geometry import Sphere
        from pydrake.multibody.tree import SpatialInertia

        h = setup.handles
        m, r = values["mass"], values["radius"]
        h.scene.ball_body.SetSpatialInertiaInBodyFrame(setup.plant_context, SpatialInertia.SolidSphereWithMass(m, r))
        if r != h.scene.nominal_ball_radius:
            for gid in h.scene.ball_geometry_ids:
                h.scene_graph.ChangeShape(setup.scene_graph_context, h.plant.get_source_id(), gid, Sphere(r))
        setup.ball_mass, setup.ball_radius = m, r


@register_effect
class ScoopFriction(Effect):
    """Ball-scoop Coulomb friction (static ``mu_static``, dynamic ``mu_dynamic``): a worn, dusty or wet
    scoop. Friction decides whether the ball rolls or slides on the funnel wall as it leaves, and so (a
    little) the release direction and speed. With the default throw the ball is catapulted out along the
    wall normal, so the effect is small (about 2 mm of landing for mu 0.1 -> 1.2); it grows for throws in
    which the ball rolls out over the rim. The proximity properties of the ball and of every scoop geometry are
    replaced in the SceneGraph Context (``SceneGraph.AssignRole(..., RoleAssign.kReplace)``) with the
    same coefficients, so the combined ball-scoop friction equals the given values. No rebuild.
    """

    name = "scoop_friction"
    params = {
        "mu_static": Param(0.6, 0.05, 1.5, "1", "static friction coefficient"),
        "mu_dynamic": Param(0.5, 0.05, 1.5, "1", "dynamic friction coefficient"),
    }

    def complete(self, values):
        out = super().complete(values)
        if out["mu_dynamic"] > out["mu_static"]:
            if values and "mu_static" not in values:
                out["mu_static"] = out["mu_dynamic"]
            else:
                raise EffectError(f"effect 'scoop_friction': mu_dynamic={out['mu_dynamic']:g} exceeds mu_static={out['mu_static']:g}")
        return out

    def apply(self, setup, values):
        from pydrake.geometry import ProximityProperties, RoleAssign
        from pydrake.multibody.plant import CoulombFriction

        h = setup.handles
        friction = CoulombFriction(values["mu_static"], values["mu_dynamic"])
        inspector = h.scene_graph.model_inspector()
        for gid in [h.scene.ball_collision_id, *h.scene.scoop_collision_ids]:
            props = ProximityProperties(inspector.GetProximityProperties(gid))
            props.UpdateProperty("material", "coulomb_friction", friction)
            h.scene_graph.AssignRole(setup.scene_graph_context, h.plant.get_source_id(), gid, props, RoleAssign.kReplace)


@register_effect
class ScoopMount(Effect):
    """Scoop mounting tilt: the scoop sits on the flange tilted by ``roll`` about the scoop frame's x axis and
    ``pitch`` about its y axis (rad; the paper's "ball-release angle", which its simulation refinement fitted).

    Physics: the ball is catapulted out of the funnel along the wall normal, so tilting the scoop on the flange
    turns the release direction with it: a pitch (about y, the axis across the default throw's swing) raises or
    lowers the release elevation (default throw, amplitude 0.4: -0.05 rad gives +2.6 degrees of elevation and a
    slower ball, 1.4 cm shorter; near the elevation of longest range the landing hardly moves, the ball's path
    does), a roll (about x) turns the release sideways (0.05 rad: 0.08 m/s sideways, 6.4 cm to one side at
    1.9 m, growing with the throw's length; a yawed base or a joint-1 offset instead turn the whole arm). The ball's rest position, its
    placement and the re-catch check all use the scoop body frame, so they follow the tilted scoop. A mounting
    bracket bent or shimmed by a few degrees is realistic; larger tilts would be seen by eye.

    Applied via the Context: the scoop is welded to the flange through the fixed joint's parent frame, a
    ``FixedOffsetFrame`` whose pose is a Context parameter (``SetPoseInParentFrame``); the tilt is composed
    after the designed mounting pose (X_PF = X_PF,nominal * R(roll, pitch, 0), about the scoop's origin).
    No rebuild; the Context reset restores the designed mounting.
    """

    name = "scoop_mount"
    params = {
        "roll": Param(0.0, -0.08, 0.08, "rad", "tilt of the scoop on the flange about the scoop frame's x axis"),
        "pitch": Param(0.0, -0.08, 0.08, "rad", "tilt of the scoop on the flange about the scoop frame's y axis"),
    }

    def apply(self, setup, values):
        if values["roll"] == 0.0 and values["pitch"] == 0.0:
            return
        from pydrake.math import RigidTransform, RollPitchYaw

        frame = scoop_mount_frame(setup.handles)
        X_nominal = frame.GetPoseInParentFrame(setup.plant_context)
        tilt = RigidTransform(RollPitchYaw(values["roll"], values["pitch"], 0.0), np.zeros(3))
        frame.SetPoseInParentFrame(setup.plant_context, X_nominal.multiply(tilt))


def scoop_mount_frame(handles):
    """The parent frame of the joint that welds the scoop body to the arm (a FixedOffsetFrame whose pose in its
    parent body is a Context parameter); EffectError when the scoop is not welded through one."""
    plant = handles.plant
    for index in plant.GetJointIndices(handles.arm):
        joint = plant.get_joint(index)
        if joint.child_body().index() == handles.scene.scoop_body.index():
            frame = joint.frame_on_parent()
            if not hasattr(frame, "SetPoseInParentFrame"):
                raise EffectError(f"scoop_mount: the scoop's joint {joint.name()!r} has no FixedOffsetFrame parent")
            return frame
    raise EffectError("scoop_mount: no joint of the arm has the scoop as its child")
