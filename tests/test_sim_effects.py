"""Physical effects: registry, validation, and each effect moves the landing the physically expected way."""

from __future__ import annotations

import numpy as np
import pytest

from besdrake.sim.effects import Effect, EffectError, Param, get_effect, list_effects, normalize_effects, register_effect, unregister_effect
from besdrake.sim.rollout import shared_rollout
from besdrake.tasks.throwing.throws import default_throw

BUILT_IN = ["base_offset", "joint_offset", "actuator_lag", "gain_scale", "air_drag", "ball_placement", "ball", "scoop_friction", "scoop_mount"]


@pytest.fixture(scope="module")
def sim():
    return shared_rollout("nominal")


@pytest.fixture(scope="module")
def base(sim):
    return sim.rollout(default_throw())


def _x(sim, effects):
    o = sim.rollout(default_throw(), effects=effects)
    assert o.ok, o.summary()
    return o


def test_registry_lists_documented_effects():
    from besdrake.task import effects_for

    # throwing's effects in their application order (another task's, e.g. the pick-and-place box's, may come between)
    assert [n for n in list_effects() if n in BUILT_IN] == BUILT_IN == effects_for("throwing")
    for name in BUILT_IN:
        e = get_effect(name)
        d = e.describe()
        assert len(d["doc"]) > 80, f"{name} needs a physics docstring"
        assert not d["needs_rebuild"]
        for key, p in d["params"].items():
            assert p["low"] <= p["nominal"] <= p["high"] and p["unit"], (name, key)


def test_unknown_and_bad_parameters_are_clear_errors():
    with pytest.raises(EffectError, match="unknown effect 'gravity_off'.*known effects"):
        get_effect("gravity_off")
    with pytest.raises(EffectError, match="no parameter"):
        normalize_effects({"base_offset": {"height": 0.1}})
    with pytest.raises(EffectError, match="outside its bounds"):
        normalize_effects({"air_drag": {"cd": 3.0}})
    with pytest.raises(EffectError, match="not finite"):
        normalize_effects({"air_drag": {"cd": float("nan")}})
    with pytest.raises(EffectError, match="must be a number"):
        normalize_effects({"air_drag": {"cd": "high"}})
    with pytest.raises(EffectError, match="exceeds mu_static"):
        normalize_effects({"scoop_friction": {"mu_static": 0.3, "mu_dynamic": 0.8}})
    assert issubclass(EffectError, ValueError)


def test_nominal_values_change_nothing(sim, base):
    eff = {name: {} for name in BUILT_IN}
    o = sim.rollout(default_throw(), effects=eff)
    assert np.allclose(o.touchdown, base.touchdown, atol=1e-9)


def test_higher_base_throws_longer(sim, base):
    up = _x(sim, {"base_offset": {"z": 0.1}}).touchdown[0]
    down = _x(sim, {"base_offset": {"z": -0.1}}).touchdown[0]
    assert down < base.touchdown[0] - 0.02 < up - 0.04


def test_base_translation_and_yaw_move_the_landing_rigidly(sim, base):
    o = _x(sim, {"base_offset": {"x": 0.1, "y": -0.05}})
    assert np.allclose(o.touchdown, base.touchdown + [0.1, -0.05], atol=1e-3)
    o = _x(sim, {"base_offset": {"yaw": 0.1}})
    assert np.arctan2(o.touchdown[1], o.touchdown[0]) == pytest.approx(0.1, abs=0.02)
    assert np.hypot(*o.touchdown) == pytest.approx(base.touchdown[0], abs=0.01)


def test_air_drag_shortens_the_throw_monotonically(sim, base):
    light = _x(sim, {"air_drag": {"cd": 0.25}}).touchdown[0]
    heavy = _x(sim, {"air_drag": {"cd": 0.5}}).touchdown[0]
    assert heavy < light < base.touchdown[0]


def test_joint_calibration_offset_moves_the_arm_but_not_the_encoders(sim, base):
    o = _x(sim, {"joint_offset": {"joint2": 0.05}})
    assert o.touchdown[0] != pytest.approx(base.touchdown[0], abs=0.01)
    # the encoders read commanded angles (tracking error only), the true arm is 0.05 rad further forward
    assert np.max(np.abs(o.q_measured - o.q_commanded)) < 0.05
    assert o.release_position[0] > base.release_position[0] + 0.02


def test_actuator_delay_shifts_the_release_and_lag_softens_the_throw(sim, base):
    d = _x(sim, {"actuator_lag": {"delay": 0.05}})
    assert d.release_time == pytest.approx(base.release_time + 0.05, abs=0.003)
    assert d.touchdown[0] == pytest.approx(base.touchdown[0], abs=0.01)
    lag = _x(sim, {"actuator_lag": {"tau": 0.03}})
    assert lag.touchdown[0] < base.touchdown[0] - 0.03
    assert lag.release_time > base.release_time


def test_gain_scale_changes_tracking_and_is_restored(sim, base):
    soft = _x(sim, {"gain_scale": {"kp_scale": 0.3, "kd_scale": 0.3}})
    err_soft = np.max(np.abs(soft.q_measured - soft.q_commanded))
    err_nom = np.max(np.abs(base.q_measured - base.q_commanded))
    assert err_soft > 2 * err_nom
    assert abs(soft.touchdown[0] - base.touchdown[0]) > 0.05
    assert np.array_equal(sim.rollout(default_throw()).touchdown, base.touchdown)


def test_ball_mass_and_radius(sim, base):
    heavy = _x(sim, {"ball": {"mass": 0.1}})
    assert abs(heavy.touchdown[0] - base.touchdown[0]) > 0.005
    big = _x(sim, {"ball": {"radius": 0.042}})
    assert big.ball_path[-1, 2] == pytest.approx(0.042)  # touchdown when the bigger ball touches the floor
    assert abs(big.touchdown[0] - base.touchdown[0]) > 0.005
    # a bigger ball has more drag
    d_small = base.touchdown[0] - _x(sim, {"air_drag": {"cd": 0.5}}).touchdown[0]
    d_big = big.touchdown[0] - _x(sim, {"ball": {"radius": 0.042}, "air_drag": {"cd": 0.5}}).touchdown[0]
    assert d_big > d_small
    assert np.array_equal(sim.rollout(default_throw()).touchdown, base.touchdown)


def test_scoop_friction_reaches_the_contact_solver(sim, base):
    slick = _x(sim, {"scoop_friction": {"mu_static": 0.1, "mu_dynamic": 0.1}})
    grippy = _x(sim, {"scoop_friction": {"mu_static": 1.5, "mu_dynamic": 1.2}})
    # small in this catapult-like release (the ball leaves along the wall normal), but real and ordered
    assert slick.touchdown[0] != grippy.touchdown[0]
    assert abs(slick.touchdown[0] - grippy.touchdown[0]) > 1e-4
    assert np.array_equal(sim.rollout(default_throw()).touchdown, base.touchdown)


def test_user_registered_effect(sim, base):
    @register_effect
    class TailWind(Effect):
        """Steady horizontal wind along +x acting on the ball in flight through the drag model."""

        name = "tail_wind_test"
        applied_via = "flight"
        params = {"speed": Param(0.0, 0.0, 10.0, "m/s")}

        def apply(self, setup, values):
            setup.wind[0] += values["speed"]

    try:
        assert "tail_wind_test" in list_effects()
        with pytest.raises(EffectError, match="already registered"):
            register_effect(TailWind)
        o = _x(sim, {"tail_wind_test": {"speed": 8.0}, "air_drag": {"cd": 0.5}})
        no_wind = _x(sim, {"air_drag": {"cd": 0.5}})
        assert o.touchdown[0] > no_wind.touchdown[0]
    finally:
        unregister_effect("tail_wind_test")
    assert "tail_wind_test" not in list_effects()


def test_an_off_centre_ball_lands_elsewhere_and_the_centred_one_is_unchanged(sim):
    plan = default_throw()
    centred = sim.rollout(plan, effects={"ball_placement": {"x": 0.0, "y": 0.0}})
    assert np.allclose(centred.touchdown, sim.rollout(plan).touchdown)
    off = sim.rollout(plan, effects={"ball_placement": {"x": 0.004, "y": 0.0}})
    assert off.ok and np.linalg.norm(off.touchdown - centred.touchdown) > 0.005


def test_a_tilted_base_turns_the_throw(sim, base):
    """Roll (about the base's forward axis) throws to the side, pitch forward lowers the release elevation."""
    rolled = _x(sim, {"base_offset": {"roll": 0.04}})
    assert abs(rolled.touchdown[1]) > 0.03
    assert _x(sim, {"base_offset": {"roll": -0.04}}).touchdown[1] * rolled.touchdown[1] < 0
    fwd, back = _x(sim, {"base_offset": {"pitch": 0.04}}), _x(sim, {"base_offset": {"pitch": -0.04}})
    el = lambda o: np.arctan2(o.release_velocity[2], np.hypot(*o.release_velocity[:2]))  # noqa: E731
    assert el(fwd) < el(base) < el(back)


def test_a_tilted_scoop_mount_turns_the_release_and_is_reset(sim, base):
    """The scoop welded tilted on the flange: a roll throws sideways (mirror-symmetric), a pitch changes the release
    elevation; the ball still starts at rest in the (tilted) funnel, and the next rollout has the designed mount."""
    left, right = _x(sim, {"scoop_mount": {"roll": -0.05}}), _x(sim, {"scoop_mount": {"roll": 0.05}})
    assert left.touchdown[1] > 0.03 and right.touchdown[1] < -0.03
    assert left.touchdown[1] == pytest.approx(-right.touchdown[1], rel=1e-3)
    up, down = _x(sim, {"scoop_mount": {"pitch": -0.05}}), _x(sim, {"scoop_mount": {"pitch": 0.05}})
    el = lambda o: np.arctan2(o.release_velocity[2], np.hypot(*o.release_velocity[:2]))  # noqa: E731
    assert el(down) < el(base) - 0.02 < el(up) - 0.04
    for o in (left, up):  # released by the throw, not dropped while the arm was still
        assert o.release_time > 0.1 and not o.flags["dropped_early"]
    again = sim.rollout(default_throw())
    assert np.allclose(again.touchdown, base.touchdown, atol=1e-9)


def test_scoop_mount_frame_is_the_welds_parent_frame(sim):
    from besdrake.tasks.throwing.effects import scoop_mount_frame

    frame = scoop_mount_frame(sim.handles)
    assert frame.body().name() != sim.handles.scene.scoop_body.name()
    X = frame.GetPoseInParentFrame(sim.handles.plant.CreateDefaultContext())
    assert np.allclose(X.GetAsMatrix4(), np.eye(4))


def test_actuator_lag_plan_keeps_every_stride_th_sample_of_the_exact_filter():
    """The lag is filtered exactly on a 1 ms grid; the commanded plan keeps every KNOT_STRIDE-th sample (and the last)
    and, between its knots, stays within a few microradians of the 1 ms filter (a plan that starts and ends at rest, as
    the task's plans do)."""
    from types import SimpleNamespace

    from besdrake.plan import MotionPlan

    lag = get_effect("actuator_lag")
    t = np.linspace(0.0, 1.0, 11)
    q = np.column_stack([0.5 * (1.0 - np.cos(np.pi * t)), 0.2 * np.sin(np.pi * t) ** 2])
    qd = np.column_stack([0.5 * np.pi * np.sin(np.pi * t), 0.2 * np.pi * np.sin(2.0 * np.pi * t)])
    setup = SimpleNamespace(plan=MotionPlan(t=t, q=q, qd=qd))
    delay, tau = 0.01, 0.02
    lag.apply(setup, {"delay": delay, "tau": tau})
    cmd = setup.plan
    assert np.allclose(np.diff(cmd.t)[:-1], lag.KNOT_STRIDE * 1e-3)
    assert cmd.t[-1] == pytest.approx(1.0 + delay + 5.0 * tau)
    # The same filter by a plain loop over the 1 ms grid, from the (delayed) plan.
    grid = np.arange(0.0, cmd.t[-1] + 5e-4, 1e-3)
    x = MotionPlan(t=t, q=q, qd=qd).sample(np.clip(grid - delay, 0.0, 1.0))
    a, y = np.exp(-1e-3 / tau), np.empty_like(x)
    y[0] = x[0]
    for k in range(1, len(grid)):
        y[k] = a * y[k - 1] + (1.0 - a) * x[k - 1]
    at_knots = np.searchsorted(grid, cmd.t - 1e-9)
    assert np.allclose(cmd.q, y[at_knots], atol=1e-12)
    assert np.max(np.abs(cmd.sample(grid) - y)) < 5e-6
