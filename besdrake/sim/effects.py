"""Physical effects: named, parameterised deviations from the simulation as designed.

An effect is what the virtual lab hides and what the diagnosis searches over, so each one

* declares its parameters (:class:`Param`: nominal no-effect value, realistic bounds, unit),
* documents the physics it models and how it is applied (Context, motion plan, or flight model),
* is deterministic and applied per rollout, after the Context has been reset, without rebuilding
  the Diagram.

Use ``effects={"base_offset": {"z": -0.03}}`` with :meth:`besdrake.sim.Rollout.rollout`. Missing
parameters take their nominal values. A user registers a new effect from their own module::

    from besdrake.sim.effects import Effect, Param, register_effect

    @register_effect
    class Wind(Effect):
        '''Constant horizontal wind on the ball in flight (m/s).'''
        name = "wind"
        params = {"vx": Param(0.0, -5.0, 5.0, "m/s")}
        def apply(self, setup, values):
            setup.wind[0] += values["vx"]

Application order is the registration order, so results do not depend on dict order.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from besdrake.plan import MotionPlan

if TYPE_CHECKING:  # pragma: no cover
    from besdrake.sim.diagram import SimHandles


class EffectError(ValueError):
    """Unknown effect, unknown parameter, or a parameter value that is not a finite number in bounds."""


@dataclass(frozen=True)
class Param:
    """One effect parameter: ``nominal`` (no effect), realistic ``low``/``high`` bounds, SI ``unit``."""

    nominal: float
    low: float
    high: float
    unit: str
    doc: str = ""


@dataclass
class RolloutSetup:
    """What effects may change for one rollout (all SI units).

    ``plan``: the commanded motion plan; ``context``/``plant_context``/``scene_graph_context``: the
    freshly reset Contexts; ``ball_radius``/``ball_mass``: used to place the ball and in flight;
    ``drag_coefficient``/``air_density``: quadratic drag in flight; ``wind``: air velocity (m/s);
    ``measurement_offset``: subtracted from the true joint angles to give the encoder readings.
    """

    plan: MotionPlan
    handles: "SimHandles"
    context: Any
    plant_context: Any
    scene_graph_context: Any
    ball_radius: float
    ball_mass: float
    drag_coefficient: float = 0.0
    air_density: float = 1.2
    wind: np.ndarray = field(default_factory=lambda: np.zeros(3))
    measurement_offset: np.ndarray | float = 0.0
    ball_offset: np.ndarray = field(default_factory=lambda: np.zeros(2))


class Effect:
    """Base class of an effect. Subclasses set ``name``, ``params`` and implement :meth:`apply`."""

    name: ClassVar[str] = ""
    params: ClassVar[dict[str, Param]] = {}
    #: How the effect is applied: "context", "plan", "flight", "actuator" (documentation and reports).
    applied_via: ClassVar[str] = "context"
    #: True when the effect changes Diagram structure (none of the built-in ones does).
    needs_rebuild: ClassVar[bool] = False

    def nominal(self) -> dict[str, float]:
        return {k: p.nominal for k, p in self.params.items()}

    def bounds(self) -> dict[str, tuple[float, float]]:
        return {k: (p.low, p.high) for k, p in self.params.items()}

    def complete(self, values: dict[str, Any] | None) -> dict[str, float]:
        """Nominal values updated by ``values``; :class:`EffectError` for unknown keys or bad numbers."""
        values = dict(values or {})
        unknown = set(values) - set(self.params)
        if unknown:
            raise EffectError(f"effect {self.name!r} has no parameter(s) {sorted(unknown)}; it has {sorted(self.params)}")
        out = self.nominal()
        for key, v in values.items():
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
                raise EffectError(f"effect {self.name!r} parameter {key!r} must be a number, got {v!r}")
            v = float(v)
            p = self.params[key]
            if not np.isfinite(v):
                raise EffectError(f"effect {self.name!r} parameter {key!r} is not finite: {v}")
            if not (p.low <= v <= p.high):
                raise EffectError(f"effect {self.name!r} parameter {key!r}={v:g} {p.unit} is outside its bounds [{p.low:g}, {p.high:g}]")
            out[key] = v
        return out

    def describe(self) -> dict[str, Any]:
        """JSON-ready description: name, doc, how applied, parameters with nominal/bounds/unit."""
        return {
            "name": self.name,
            "doc": (type(self).__doc__ or "").strip(),
            "applied_via": self.applied_via,
            "needs_rebuild": self.needs_rebuild,
            "params": {k: {"nominal": p.nominal, "low": p.low, "high": p.high, "unit": p.unit, "doc": p.doc} for k, p in self.params.items()},
        }

    def apply(self, setup: RolloutSetup, values: dict[str, float]) -> None:  # pragma: no cover - abstract
        raise NotImplementedError


_REGISTRY: dict[str, Effect] = {}


def register_effect(effect: type[Effect] | Effect, *, replace: bool = False):
    """Register an effect class (usable as a decorator) or instance under its ``name``."""
    inst = effect() if isinstance(effect, type) else effect
    if not isinstance(inst, Effect):
        raise TypeError(f"register_effect needs an Effect subclass or instance, got {effect!r}")
    if not inst.name or not isinstance(inst.name, str):
        raise EffectError(f"effect {effect!r} needs a non-empty string name")
    for key, p in inst.params.items():
        if not (p.low <= p.nominal <= p.high):
            raise EffectError(f"effect {inst.name!r} parameter {key!r}: nominal {p.nominal} outside [{p.low}, {p.high}]")
    if inst.name in _REGISTRY and not replace:
        raise EffectError(f"an effect named {inst.name!r} is already registered (pass replace=True)")
    _REGISTRY[inst.name] = inst
    return effect


def unregister_effect(name: str) -> None:
    """Remove a registered effect (mainly for tests of user effects)."""
    _REGISTRY.pop(name, None)


def get_effect(name: str) -> Effect:
    """The registered effect ``name``; :class:`EffectError` listing the known names otherwise."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise EffectError(f"unknown effect {name!r}; known effects: {list_effects()}") from None


def list_effects() -> list[str]:
    """Names of the registered effects, in application order."""
    return list(_REGISTRY)


def normalize_effects(effects: dict[str, dict[str, Any]] | None) -> dict[str, dict[str, float]]:
    """Validate ``{name: {param: value}}`` and complete it with nominal values."""
    if effects is None:
        return {}
    if not isinstance(effects, dict):
        raise EffectError(f"effects must be a mapping {{name: {{param: value}}}}, got {type(effects).__name__}")
    out = {}
    for name, values in effects.items():
        eff = get_effect(str(name))
        if values is not None and not isinstance(values, dict):
            raise EffectError(f"effect {name!r} parameters must be a mapping, got {values!r}")
        out[str(name)] = eff.complete(values)
    return out


def merge_effects(base: dict[str, dict[str, float]], extra: dict[str, dict[str, Any]] | None) -> dict[str, dict[str, float]]:
    """Scenario effects updated by per-rollout ones (per parameter), validated and completed."""
    merged = {k: dict(v) for k, v in base.items()}
    for name, values in (extra or {}).items():
        if not isinstance(values, dict) and values is not None:
            raise EffectError(f"effect {name!r} parameters must be a mapping, got {values!r}")
        merged.setdefault(str(name), {}).update(values or {})
    return normalize_effects(merged)


def apply_effects(setup: RolloutSetup, effects: dict[str, dict[str, float]]) -> None:
    """Apply completed effects to ``setup`` in registration order."""
    for name in list_effects():
        if name in effects:
            try:
                _REGISTRY[name].apply(setup, effects[name])
            except (KeyboardInterrupt, EffectError):
                raise
            except SystemExit as err:  # a plugin must not end the process (or a pool worker)
                raise EffectError(f"effect {name!r} called sys.exit({err.code!r}) in apply()") from None
            except Exception as err:  # a user's effect: name it rather than show its traceback
                raise EffectError(f"effect {name!r} failed in apply(): {type(err).__name__}: {err}") from err


# ---------------------------------------------------------------------------------------- built-ins


@register_effect
class BaseOffset(Effect):
    """Base pose offset: the arm stands somewhere other than designed (pedestal height, placement, yaw, tilt).

    The arm is welded to a FixedOffsetFrame whose pose is a Context parameter; the offset is composed
    with the scenario's base pose (translation added in the world frame, yaw added about world z; roll and
    pitch tilt the base about its own forward x and sideways y axes, R = Rz(yaw) Ry(pitch) Rx(roll), e.g. an
    uneven floor or a pedestal that leans). A higher base gives a longer throw; a base pitched forward
    lowers the release elevation, a rolled base throws to the side. A base yaw is the same rotation about the
    same vertical axis as a joint-1 encoder offset (joint 1 turns about the base's z axis through its origin):
    no throw separates the two. Applied via the Context, no rebuild.
    """

    name = "base_offset"
    params = {
        "x": Param(0.0, -0.2, 0.2, "m", "forward offset of the base"),
        "y": Param(0.0, -0.2, 0.2, "m", "lateral offset of the base"),
        "z": Param(0.0, -0.2, 0.2, "m", "height offset of the base"),
        "yaw": Param(0.0, -0.2, 0.2, "rad", "rotation of the base about the vertical"),
        "roll": Param(0.0, -0.05, 0.05, "rad", "tilt of the base about its forward (x) axis"),
        "pitch": Param(0.0, -0.05, 0.05, "rad", "tilt of the base about its sideways (y) axis"),
    }

    def apply(self, setup, values):
        from pydrake.math import RigidTransform, RollPitchYaw

        h = setup.handles
        b = h.scenario.base
        X = RigidTransform(
            RollPitchYaw(values["roll"], values["pitch"], b.yaw + values["yaw"]),
            [b.x + values["x"], b.y + values["y"], b.z + values["z"]],
        )
        h.base_frame.SetPoseInParentFrame(setup.plant_context, X)


#: Number of arm joints (from the base) whose encoder offsets the ``joint_offset`` effect declares.
OFFSET_JOINTS = 6


@register_effect
class JointOffset(Effect):
    """Joint calibration offsets: the encoder zero of the K-th arm joint is off by ``jointK`` rad.

    The parameters number the arm's joints from the base (``joint1`` is the first joint in the robot file);
    the registry declares the first :data:`OFFSET_JOINTS` of them (a longer arm's further joints are taken
    as calibrated).

    The servo drives the *encoder* reading to the command, so the true angle is command + offset:
    the commanded plan is shifted by the offsets, and the reported measured joint trajectory is the
    encoder reading (true - offset), as on the real robot. Applied via the motion plan, no rebuild.
    """

    name = "joint_offset"
    applied_via = "plan"
    params = {f"joint{k}": Param(0.0, -0.1, 0.1, "rad", f"encoder zero offset of arm joint {k}") for k in range(1, OFFSET_JOINTS + 1)}

    def apply(self, setup, values):
        n = setup.plan.q.shape[1]
        off = np.array([values.get(f"joint{k}", 0.0) for k in range(1, n + 1)])
        if not np.any(off):
            return
        p = setup.plan
        setup.plan = MotionPlan(t=p.t.copy(), q=p.q + off, qd=None if p.qd is None else p.qd.copy(), meta=dict(p.meta), joint_names=p.joint_names)
        setup.measurement_offset = setup.measurement_offset + off


@register_effect
class ActuatorLag(Effect):
    """Actuator delay and lag: the command reaches the joints ``delay`` s late and through a first-order
    low-pass with time constant ``tau`` s (drive bandwidth), the same for all joints.

    Applied to the commanded trajectory: q_cmd(t) = LowPass_tau[q_plan(t - delay)], computed exactly on a
    1 ms grid (zero-order-hold discretisation of 1/(tau s + 1)), held at the plan's start before the delay.
    The plan is extended by the delay so the motion completes. No rebuild. A lag slows the effective swing,
    delays the release and changes the throw.
    """

    name = "actuator_lag"
    applied_via = "plan"
    params = {
        "delay": Param(0.0, 0.0, 0.1, "s", "pure transport delay of the command"),
        "tau": Param(0.0, 0.0, 0.1, "s", "first-order lag time constant of the drives"),
    }

    def apply(self, setup, values):
        delay, tau = values["delay"], values["tau"]
        if delay == 0.0 and tau == 0.0:
            return
        p = setup.plan
        dt = 0.001
        T = p.duration + delay + 5.0 * tau
        t = np.arange(0.0, T + dt / 2, dt)
        q = p.sample(np.clip(t - delay, 0.0, p.duration))
        if tau > 0.0:
            from scipy.signal import lfilter

            # exact ZOH step of the first-order lag, y[k] = a y[k-1] + (1 - a) q[k-1] from y[0] = q[0]
            # (one vectorised filter, about 60x faster than a Python loop over the 1 ms grid, per rollout)
            a = np.exp(-dt / tau)
            q = q[0] + lfilter([0.0, 1.0 - a], [1.0, -a], q - q[0], axis=0)
        qd = np.gradient(q, t, axis=0)
        setup.plan = MotionPlan(t=t, q=q, qd=qd, meta=dict(p.meta), joint_names=p.joint_names)


@register_effect
class GainScale(Effect):
    """Servo gain scale: the joint PD gains are ``kp_scale``/``kd_scale`` times the scenario's (a weaker or
    stiffer drive tuning). Lower gains track the swing less tightly: the arm lags and overshoots, and the
    throw changes. In pydrake 1.51 the PD gains are not Context parameters (``JointActuator.set_controller_gains``
    has no Context overload) but are read from the actuator at every step, so the effect sets them on the
    actuators of this process's Diagram and :class:`~besdrake.sim.Rollout` restores the scenario's gains at
    the next reset. No rebuild.
    """

    name = "gain_scale"
    applied_via = "actuator"
    params = {
        "kp_scale": Param(1.0, 0.2, 2.0, "1", "factor on the proportional gains"),
        "kd_scale": Param(1.0, 0.2, 2.0, "1", "factor on the damping gains"),
    }

    def apply(self, setup, values):
        if values["kp_scale"] == 1.0 and values["kd_scale"] == 1.0:
            return
        set_gains(setup.handles, values["kp_scale"], values["kd_scale"])


def set_gains(handles: "SimHandles", kp_scale: float = 1.0, kd_scale: float = 1.0) -> None:
    """Set the joint PD gains to the scenario's times the scales (1, 1 restores them)."""
    from pydrake.multibody.tree import PdControllerGains

    c = handles.scenario.controller
    for i, act in enumerate(handles.actuators):
        act.set_controller_gains(PdControllerGains(p=c.kp[i] * kp_scale, d=c.kd[i] * kd_scale))
    handles.gains_scaled = (kp_scale, kd_scale) != (1.0, 1.0)


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
        h.ball_body.SetSpatialInertiaInBodyFrame(setup.plant_context, SpatialInertia.SolidSphereWithMass(m, r))
        if r != h.nominal_ball_radius:
            for gid in h.ball_geometry_ids:
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
        for gid in [h.ball_collision_id, *h.scoop_collision_ids]:
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


def scoop_mount_frame(handles: "SimHandles"):
    """The parent frame of the joint that welds the scoop body to the arm (a FixedOffsetFrame whose pose in its
    parent body is a Context parameter); EffectError when the scoop is not welded through one."""
    plant = handles.plant
    for index in plant.GetJointIndices(handles.arm):
        joint = plant.get_joint(index)
        if joint.child_body().index() == handles.scoop_body.index():
            frame = joint.frame_on_parent()
            if not hasattr(frame, "SetPoseInParentFrame"):
                raise EffectError(f"scoop_mount: the scoop's joint {joint.name()!r} has no FixedOffsetFrame parent")
            return frame
    raise EffectError("scoop_mount: no joint of the arm has the scoop as its child")
