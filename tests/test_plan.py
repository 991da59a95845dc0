"""MotionPlan: validation, interpolation, limit report and JSON round trip."""

from __future__ import annotations

import json

import numpy as np
import pytest

from besdrake.robot import JointLimits
from besdrake.plan import LimitReport, MotionPlan, PlanError


from besdrake.robot import load_robot

COMPI = load_robot("compi")


def _plan(n=50, T=1.0, amp=0.5, with_qd=True):
    t = np.linspace(0.0, T, n)
    w = 2 * np.pi / T
    q = amp * np.sin(np.outer(t, [w] * 6))
    qd = amp * w * np.cos(np.outer(t, [w] * 6)) if with_qd else None
    return MotionPlan(t=t, q=q, qd=qd)


def test_validate_accepts_good_plan_and_duration():
    p = _plan()
    assert p.validate() is p
    assert p.duration == pytest.approx(1.0)


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda p: setattr(p, "q", p.q[:, :5]), "shape"),
        (lambda p: p.q.__setitem__((3, 2), np.nan), "NaN"),
        (lambda p: p.t.__setitem__(4, np.inf), "NaN or inf"),
        (lambda p: p.t.__setitem__(5, p.t[4]), "increase"),
        (lambda p: setattr(p, "t", p.t + 0.5), "start at 0"),
        (lambda p: setattr(p, "qd", p.qd[:-1]), "qd must have"),
        (lambda p: (setattr(p, "t", p.t[:1]), setattr(p, "q", p.q[:1])), "at least 2"),
    ],
)
def test_validate_rejects_bad_plans(change, match):
    p = _plan()
    change(p)
    with pytest.raises(PlanError, match=match):
        p.validate()


def test_plan_error_is_value_error():
    assert issubclass(PlanError, ValueError)


@pytest.mark.parametrize("with_qd", [True, False])
def test_numpy_interpolation_matches_drake_trajectory(with_qd):
    p = _plan(with_qd=with_qd)
    traj = p.trajectory()
    ts = np.random.default_rng(0).uniform(0, p.duration, 40)
    for d in (0, 1, 2):
        drake = (traj if d == 0 else traj.derivative(d)).vector_values(ts).T
        assert np.allclose(p.sample(ts, d), drake, atol=1e-8 * (1 + 100 * d))
    assert np.allclose(p.sample(p.t), p.q)


def test_check_limits_reports_each_kind():
    ok = _plan(T=2.0, amp=0.2)
    rep = ok.check_limits(COMPI.limits)
    assert isinstance(rep, LimitReport) and rep.ok and rep.violations() == []
    big = _plan(T=1.0, amp=2.5)  # beyond joint2/3/5 limits, 15.7 rad/s, ~99 rad/s^2
    rep = big.check_limits(COMPI.limits)
    assert not rep.ok
    assert rep.position[1] == pytest.approx(max(2.5 - 2.09, 2.5 - 1.8), abs=1e-3)  # lower limit -1.8 is worse
    assert rep.position[2] == pytest.approx(2.5 - 2.3, abs=1e-3)
    assert rep.position[0] == 0.0  # +-pi not reached by 2.5 rad
    assert rep.velocity[0] == pytest.approx(2.5 * 2 * np.pi - 3.14, rel=1e-3)
    assert np.all(rep.acceleration > 0)
    assert any("joint2 position" in v for v in rep.violations())
    # custom limits
    wide = JointLimits(COMPI.joint_names, np.tile([-3.0, 3.0], (6, 1)), np.full(6, 100.0), np.full(6, 1e3))
    assert big.check_limits(wide).ok
    with pytest.raises(PlanError, match="7 joints"):
        MotionPlan(t=[0.0, 1.0], q=np.zeros((2, 7))).check_limits(COMPI.limits)
    with pytest.raises(PlanError, match="differ"):
        MotionPlan(t=[0.0, 1.0], q=np.zeros((2, 6)), joint_names=tuple("abcdef")).check_limits(COMPI.limits)


def test_json_round_trip(tmp_path):
    p = _plan()
    p.meta = {"source": "test"}
    path = p.save(tmp_path / "plan.json")
    q = MotionPlan.load(path)
    assert np.array_equal(q.t, p.t) and np.array_equal(q.q, p.q) and np.array_equal(q.qd, p.qd)
    assert q.meta == {"source": "test"}
    d = json.loads(path.read_text())
    assert "joint_names" not in d  # a plan without names is written without them
    named = MotionPlan.load(MotionPlan(t=p.t, q=p.q, joint_names=COMPI.joint_names).save(tmp_path / "named.json"))
    assert named.joint_names == COMPI.joint_names
    no_qd = MotionPlan.from_dict({"t": [0, 1], "q": [[0] * 6, [0.1] * 6]})
    assert no_qd.qd is None


def test_load_errors(tmp_path):
    with pytest.raises(PlanError, match="not found"):
        MotionPlan.load(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(PlanError, match="not valid JSON"):
        MotionPlan.load(bad)
    with pytest.raises(PlanError, match="missing key"):
        MotionPlan.from_dict({"t": [0, 1]})
    with pytest.raises(PlanError, match="joint_names"):
        MotionPlan.from_dict({"t": [0, 1], "q": [[0] * 6] * 2, "joint_names": ["a"] * 6})
    with pytest.raises(PlanError, match="NaN"):
        MotionPlan.from_dict({"t": [0, 1], "q": [[0] * 6, [float("nan")] * 6]})
    with pytest.raises(PlanError, match="numeric or ragged"):
        MotionPlan.from_dict({"t": [0, 1], "q": [[0] * 6, [0] * 5]})


def test_limit_checks_keep_the_per_sample_figures_and_follow_a_changed_plan():
    """The peaks kept on a plan give the figures of the per-sample form, and a plan changed in place is sampled anew."""
    p = _plan(T=1.0, amp=2.5)
    lim = COMPI.limits
    rep = p.check_limits(lim)
    q, qd, qdd = p._sampled(0.002)
    pos = lim.position
    assert np.array_equal(rep.position, np.maximum(np.maximum(np.max(pos[:, 0] - q, axis=0), np.max(q - pos[:, 1], axis=0)), 0.0))
    assert np.array_equal(rep.velocity, np.maximum(np.max(np.abs(qd) - lim.velocity, axis=0), 0.0))
    assert np.array_equal(rep.acceleration, np.maximum(np.max(np.abs(qdd) - lim.acceleration, axis=0), 0.0))
    vel, acc = p.peak_limit_ratios(lim)
    assert np.array_equal(vel, np.max(np.abs(qd), axis=0) / lim.velocity)
    assert np.array_equal(acc, np.max(np.abs(qdd), axis=0) / lim.acceleration)
    p.q *= 0.01  # in place: the kept peaks no longer apply
    p.qd *= 0.01
    fresh = MotionPlan(t=p.t.copy(), q=p.q.copy(), qd=p.qd.copy())
    assert p.check_limits(lim).ok
    assert np.array_equal(p.peak_limit_ratios(lim)[1], fresh.peak_limit_ratios(lim)[1])
    assert np.array_equal(p.peak_limit_ratios(lim, resolution=0.01)[0], fresh.peak_limit_ratios(lim, resolution=0.01)[0])


def test_a_plan_whose_interpolation_overflows_fails_its_limits_quietly():
    import warnings

    from besdrake.sim.scenario import load_scenario

    limits = load_scenario("nominal").robot.limits
    t = np.array([0.0, 1e-300, 1.0])
    q = np.zeros((3, 6))
    q[1, 0] = 1e10
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow warning escapes
        try:
            report = MotionPlan(t, q).check_limits(limits)
        except PlanError:
            return  # refused as malformed: as good
    assert not report.ok and np.all(np.isfinite(report.position) | np.isinf(report.position))
    assert report.velocity[0] > 0 and report.acceleration[0] > 0


def test_slowed_after_keeps_the_path_and_slows_only_what_follows():
    """The time warp of a template's follow-through (issue 27): the plan up to ``at`` knot for knot, the same path
    after it, played ``factor`` x as fast once the ``window`` has passed."""
    t = np.linspace(0.0, 1.0, 101)
    plan = MotionPlan(t, np.column_stack([t, t**2]), qd=np.column_stack([np.ones_like(t), 2 * t]))
    slow = plan.slowed_after(0.4, 0.5, window=0.2)
    before = plan.t <= 0.4
    assert np.array_equal(slow.t[: before.sum()], plan.t[before]) and np.array_equal(slow.q[: before.sum()], plan.q[before])
    assert np.allclose(slow.q[:, 1], slow.q[:, 0] ** 2, atol=1e-6)  # still on the path
    assert slow.q[-1] == pytest.approx(plan.q[-1])
    sigma = np.linspace(0.4, 0.6, 2001)
    rate = 1.0 - 0.5 * 0.5 * (1.0 - np.cos(np.pi * (sigma - 0.4) / 0.2))
    window_time = float(np.sum(0.5 * (1 / rate[1:] + 1 / rate[:-1]) * np.diff(sigma)))
    assert slow.duration == pytest.approx(0.4 + window_time + 0.4 / 0.5, abs=1e-6)
    after = slow.t > 0.4 + window_time + 1e-6
    assert np.allclose(slow.qd[after, 0], 0.5) and np.allclose(slow.sample(slow.t[after], 1)[:, 0], 0.5, atol=1e-6)
    assert plan.slowed_after(0.4, 1.0).q[-1] == pytest.approx(plan.q[-1])
    end = plan.slowed_after(plan.duration, 0.5)  # nothing follows the end: the plan as it is
    assert np.array_equal(end.t, plan.t) and np.array_equal(end.q, plan.q)
    limits = JointLimits(("a", "b"), np.array([[-5.0, 5.0]] * 2), np.array([0.1, 0.1]), np.array([100.0, 100.0]))
    assert plan.with_follow_through_within(limits, plan.duration) is plan
    for bad in ((0.4, 0.0), (1.5, 0.5), (np.nan, 0.5)):
        with pytest.raises(PlanError):
            plan.slowed_after(*bad)


def test_peak_limit_ratios_until_a_time_see_only_the_plan_before_it():
    t = np.linspace(0.0, 1.0, 101)
    q = np.column_stack([np.where(t < 0.5, 0.2 * t, 0.1 + 2.0 * (t - 0.5)), np.zeros_like(t)])
    plan = MotionPlan(t, q)
    limits = JointLimits(("a", "b"), np.array([[-5.0, 5.0]] * 2), np.array([1.0, 1.0]), np.array([100.0, 100.0]))
    full_v, full_a = plan.peak_limit_ratios(limits)
    early_v, early_a = plan.peak_limit_ratios(limits, until=0.4)
    assert full_v[0] > 1.5 and early_v[0] < 0.3 and np.all(early_a <= full_a + 1e-12)
    same_v, same_a = plan.peak_limit_ratios(limits, until=plan.duration)
    assert np.allclose(same_v, full_v) and np.allclose(same_a, full_a)


def test_a_plan_stopped_after_a_time_brakes_every_joint_to_rest_within_its_limits():
    from besdrake.robot import load_robot

    robot = load_robot("compi")
    t = np.linspace(0.0, 1.0, 101)
    q = np.outer(np.sin(2.0 * t), np.linspace(0.2, 1.2, 6))  # every joint still moving at 0.5 s
    plan = MotionPlan(t=t, q=q, qd=np.outer(2.0 * np.cos(2.0 * t), np.linspace(0.2, 1.2, 6)))
    stopped = plan.stopped_after(0.5, robot.limits, share=0.5)
    k = int(np.searchsorted(t, 0.5))
    assert np.array_equal(stopped.t[: k + 1], t[: k + 1]) and np.array_equal(stopped.q[: k + 1], q[: k + 1])
    assert np.all(stopped.qd[-1] == 0.0) and stopped.meta["stopped_after_s"] == pytest.approx(0.5)
    v0 = plan.qd[k]
    acc = np.abs(stopped.sample(np.linspace(0.51, stopped.duration, 200), 2))
    assert acc.max() <= 0.5 * robot.limits.acceleration.max() + 1e-6  # the joint that needs longest brakes at half its limit
    travel = stopped.q[-1] - q[k]
    stop = stopped.duration - t[k]
    assert np.allclose(travel, 0.5 * v0 * stop)  # constant deceleration: half the speed times the time to stop
    assert np.all(np.diff(stopped.t) > 0) and stopped.check_limits(robot.limits).ok
    assert plan.stopped_after(1.0, robot.limits) is plan  # nothing follows
    with pytest.raises(PlanError):
        plan.stopped_after(0.5, robot.limits, share=0.0)
