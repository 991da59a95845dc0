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
        '''A constant offset (m) on the encoder readings of every joint.'''
        name = "encoder_bias"
        params = {"q": Param(0.0, -0.05, 0.05, "rad")}
        def apply(self, setup, values):
            setup.measurement_offset = setup.measurement_offset + values["q"]

Application order is the registration order, so results do not depend on dict order. The effects below act on
any robot; a task registers the effects on its own scene in its folder (``besdrake/tasks/<name>/effects.py``,
e.g. the object's mass), loaded before the registry is first read (:func:`besdrake.task.load_task_effects`), and
its rollout hands them a :class:`RolloutSetup` subclass with the fields they change.
"""

from __future__ import annotations

from dataclasses import dataclass
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
    """What effects may change for one rollout (all SI units); a task's rollout may hand its effects a subclass with
    more fields (its scene's objects).

    ``plan``: the commanded motion plan; ``context``/``plant_context``/``scene_graph_context``: the
    freshly reset Contexts; ``measurement_offset``: subtracted from the true joint angles to give the encoder readings.
    """

    plan: MotionPlan
    handles: "SimHandles"
    context: Any
    plant_context: Any
    scene_graph_context: Any
    measurement_offset: np.ndarray | float = 0.0


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
_TASK_EFFECTS_LOADED = False


def _load_task_effects() -> None:
    """Register the built-in tasks' effects once, after the built-ins below (so the application order is the same
    in every process: built-ins, then the tasks', then a user's)."""
    global _TASK_EFFECTS_LOADED
    if not _TASK_EFFECTS_LOADED:
        _TASK_EFFECTS_LOADED = True
        from besdrake.task import load_task_effects

        load_task_effects()


def register_effect(effect: type[Effect] | Effect, *, replace: bool = False):
    """Register an effect class (usable as a decorator) or instance under its ``name``."""
    if _BUILTINS_DONE:
        _load_task_effects()
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
    _load_task_effects()
    try:
        return _REGISTRY[name]
    except KeyError:
        raise EffectError(f"unknown effect {name!r}; known effects: {list_effects()}") from None


def list_effects() -> list[str]:
    """Names of the registered effects, in application order."""
    _load_task_effects()
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
_BUILTINS_DONE = False  # True below: a later registration (a task's, a user's) comes after the tasks' effects


@register_effect
class BaseOffset(Effect):
    """Base pose offset: the arm stands somewhere other than designed (pedestal height, placement, yaw, tilt).

    The arm is welded to a FixedOffsetFrame whose pose is a Context parameter; the offset is composed
    with the scenario's base pose (translation added in the world frame, yaw added about world z; roll and
    pitch tilt the base about its own forward x and sideways y axes, R = Rz(yaw) Ry(pitch) Rx(roll), e.g. an
    uneven floor or a pedestal that leans). A higher base moves every tool pose up; a base pitched forward
    tilts the tool's path down, a rolled base turns it to the side. A base yaw is the same rotation about the
    same vertical axis as a joint-1 encoder offset (joint 1 turns about the base's z axis through its origin):
    no movement separates the two. Applied via the Context, no rebuild.
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
    delays every event of the task (e.g. a release) and changes the outcome. The commanded plan keeps every
    :attr:`KNOT_STRIDE`-th sample of that grid (with its velocity): the simulation's cost grows with the knots (a
    1 ms plan took 2.3x as long to simulate as a 5 ms one), while the outcomes differ by well under a micrometre.
    """

    #: Samples of the 1 ms filter grid per knot of the commanded plan (5: 5 ms knots; measured on the learn run's 25
    #: diagnosis plans at delay 10 ms, tau 20 ms: touchdowns within 0.4 um and joint paths within 1e-8 rad of the
    #: 1 ms plan's, 204 -> 90 ms per rollout).
    KNOT_STRIDE = 5

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
        keep = np.unique(np.r_[np.arange(0, t.size, max(1, self.KNOT_STRIDE)), t.size - 1])
        setup.plan = MotionPlan(t=t[keep], q=q[keep], qd=qd[keep], meta=dict(p.meta), joint_names=p.joint_names)


@register_effect
class GainScale(Effect):
    """Servo gain scale: the joint PD gains are ``kp_scale``/``kd_scale`` times the scenario's (a weaker or
    stiffer drive tuning). Lower gains track the swing less tightly: the arm lags and overshoots, and the
    outcome changes. In pydrake 1.51 the PD gains are not Context parameters (``JointActuator.set_controller_gains``
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


_BUILTINS_DONE = True
