"""Rollout: the black box. Landing, release, flags, determinism, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from besdrake.plan import MotionPlan, PlanError
from besdrake.tasks.throwing.outcome import Outcome
from besdrake.sim.rollout import PlanLimitError, shared_rollout
from besdrake.tasks.throwing.throws import START_POSE, default_throw


@pytest.fixture(scope="module")
def sim():
    return shared_rollout("nominal")


@pytest.fixture(scope="module")
def nominal(sim):
    return sim.rollout(default_throw())


def test_default_throw_lands_in_front_between_1_and_2_5_m(nominal):
    o = nominal
    assert o.ok, o.summary()
    assert 1.0 < o.touchdown[0] < 2.5 and abs(o.touchdown[1]) < 1e-6
    assert 0.05 < o.release_time < o.touchdown_time < 2.0
    assert np.linalg.norm(o.release_velocity) > 1.0
    # the path ends with the ball touching the floor, and starts in the scoop above the pedestal
    assert o.ball_path[-1, 2] == pytest.approx(0.035, abs=1e-9)
    assert np.allclose(o.ball_path[-1, :2], o.touchdown)
    assert o.ball_path[0, 2] > 1.0
    assert np.all(np.diff(o.ball_t) > 0)


def test_measured_joints_track_the_plan(nominal):
    o = nominal
    assert o.q_measured.shape == o.q_commanded.shape == (o.joint_t.size, 6)
    assert np.max(np.abs(o.q_measured - o.q_commanded)) < 0.05


def test_rollouts_are_deterministic_and_reset(sim, nominal):
    again = sim.rollout(default_throw())
    assert np.array_equal(again.ball_path, nominal.ball_path)
    assert np.array_equal(again.q_measured, nominal.q_measured)
    sim.rollout(default_throw(amplitude=0.5), effects={"ball": {"radius": 0.04}, "gain_scale": {"kp_scale": 0.5}})
    after = sim.rollout(default_throw())
    assert np.array_equal(after.touchdown, nominal.touchdown)


def test_landing_is_smooth_and_monotonic_in_amplitude(sim):
    amps = np.linspace(0.25, 0.45, 5)
    x = np.array([sim.rollout(default_throw(amplitude=a)).touchdown[0] for a in amps])
    steps = np.diff(x)
    assert np.all(steps > 0)
    assert np.max(np.abs(np.diff(steps))) < 0.5 * np.median(steps)  # no jumps: nearly linear locally


def test_yaw_turns_the_throw(sim):
    o = sim.rollout(default_throw(yaw=0.3))
    assert o.ok and o.touchdown[1] > 0.2
    assert np.arctan2(o.touchdown[1], o.touchdown[0]) == pytest.approx(0.3, abs=0.05)


def test_never_released_when_the_arm_holds_still(sim):
    t = np.linspace(0, 1.0, 11)
    plan = MotionPlan(t=t, q=np.tile(START_POSE, (11, 1)))
    o = sim.rollout(plan)
    assert o.flags["never_released"] and not o.ok
    assert o.touchdown is None and o.release_time is None
    assert o.sim_time == pytest.approx(1.0 + sim.scenario.release.tail)


def test_tiny_swing_drops_the_ball_early(sim):
    o = sim.rollout(default_throw(amplitude=0.1))
    assert o.flags["dropped_early"] and not o.ok
    assert o.touchdown is not None and o.touchdown[0] < 0.5
    assert np.linalg.norm(o.release_velocity) < sim.scenario.release.min_speed
    assert "fell out" in o.message
    # an even smaller swing keeps the ball in the scoop
    assert sim.rollout(default_throw(amplitude=0.03)).flags["never_released"]


def test_bad_plans_raise_clear_errors(sim):
    p = default_throw()
    p.q[10, 2] = np.nan
    with pytest.raises(PlanError, match="NaN"):
        sim.rollout(p)
    with pytest.raises(PlanError, match="MotionPlan"):
        sim.rollout({"t": [0, 1]})
    far = default_throw(amplitude=4.0)  # joint 2 beyond 2.09 rad
    with pytest.raises(PlanLimitError, match="joint2 position"):
        sim.rollout(far)
    with pytest.raises(ValueError, match="limits"):
        sim.rollout(default_throw(), limits="ignore")


def test_limit_violations_are_flagged_on_request(sim):
    o = sim.rollout(default_throw(amplitude=4.0), limits="flag")
    assert o.flags["joint_limit_exceeded"] and not o.ok


def test_solver_failure_is_a_flagged_outcome(sim):
    class Exploding:
        def Initialize(self):
            pass

        def AdvanceTo(self, t):
            raise RuntimeError("solver did not converge")

    real = sim.simulator
    sim.simulator = Exploding()
    try:
        o = sim.rollout(default_throw())
    finally:
        sim.simulator = real
    assert o.flags["sim_failed"] and not o.ok and "did not converge" in o.message
    assert sim.rollout(default_throw()).ok  # the Rollout is still usable


def test_outcome_json_round_trip(nominal):
    d = json.loads(nominal.to_json())
    back = Outcome.from_dict(d)
    assert np.allclose(back.touchdown, nominal.touchdown)
    assert np.allclose(back.ball_path, nominal.ball_path)
    assert back.flags == nominal.flags and back.ok
    assert d["effects"] == {} and d["scenario"] == "nominal"


def test_plan_ending_in_motion_holds_its_last_position(sim):
    full = default_throw(amplitude=0.3)
    cut = int(np.searchsorted(full.t, 0.15))  # ends mid-swing, at speed
    plan = MotionPlan(t=full.t[: cut + 1], q=full.q[: cut + 1], qd=full.qd[: cut + 1])
    assert np.any(np.abs(plan.qd[-1]) > 0.5)
    o = sim.rollout(plan)
    assert o.ok or o.flags["dropped_early"]  # the sudden stop throws the ball
    # after its end the plan commands its last position at rest
    src = sim.handles.plan_source
    ctx = src.GetMyContextFromRoot(sim.context)
    sim.context.SetTime(plan.duration + 0.1)
    desired = src.get_output_port().Eval(ctx)
    assert np.allclose(desired[:6], plan.q[-1], atol=1e-3) and np.allclose(desired[6:], 0.0)


def test_initial_hold_is_skipped_but_reported_in_plan_time(sim):
    short = sim.rollout(default_throw(amplitude=0.3, hold=0.03))
    long = sim.rollout(default_throw(amplitude=0.3, hold=0.5))
    # the arm and ball start at their static equilibrium, so a longer hold changes nothing but the clock
    assert long.touchdown[0] == pytest.approx(short.touchdown[0], abs=1e-6)
    assert long.release_time == pytest.approx(short.release_time + 0.47, abs=1e-9)
    assert long.joint_t[0] == 0.0 and long.ball_t[0] == 0.0
    assert np.all(np.diff(long.joint_t) > 0)
    # the reported measured joints hold still during the skipped part and track the plan afterwards
    assert np.max(np.abs(long.q_measured - long.q_commanded)) < 0.05


def test_diverging_state_is_a_flagged_outcome(sim, monkeypatch):
    place = type(sim)._place_ball

    def kicked(self, *args):  # an absurd ball speed stands in for a numerical blow-up
        place(self, *args)
        self.handles.plant.SetVelocities(self.plant_context, self.handles.scene.ball_instance, [0, 0, 0, 0, 0, 80.0])

    monkeypatch.setattr(type(sim), "_place_ball", kicked)
    o = sim.rollout(default_throw())
    assert o.flags["sim_failed"] and "diverged" in o.message and not o.ok
    monkeypatch.undo()
    assert sim.rollout(default_throw()).ok


def test_release_check_stops_where_the_contact_results_of_every_step_did(sim, monkeypatch):
    """The rollout's plant computes its output ports only when read and its release check reads the contact results
    only off the scoop's surfaces; a rollout whose plant samples them at every step (the contact results of the last
    step, free to read) stops at the same step with the same outcome, and the cheap rollout reads the contact results
    at a few of its checks only."""
    from besdrake.tasks.throwing.rollout import ThrowRollout

    class SampledPorts(ThrowRollout):
        sampled_output_ports = True

    ref, reads = SampledPorts("nominal"), []
    touching = sim._ball_touching
    monkeypatch.setattr(sim, "_ball_touching", lambda: reads.append(1) or touching())
    for plan, effects in ((default_throw(amplitude=0.2), None), (default_throw(amplitude=0.5), {"ball_placement": {"x": 0.004}}),
                          (default_throw(amplitude=0.1), None)):
        reads.clear()
        o, r = sim.rollout(plan, effects), ref.rollout(plan, effects)
        assert o.flags == r.flags and o.sim_time == r.sim_time
        assert np.array_equal(o.touchdown, r.touchdown) and np.array_equal(o.q_measured, r.q_measured)
        checks = round(o.sim_time / sim.scenario.release.check_interval)
        assert 0 < len(reads) <= max(3, checks // 4), (len(reads), checks)
