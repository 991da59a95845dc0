"""The 49-parameter throw policy vector and its motion plans."""

from __future__ import annotations

import numpy as np
import pytest

from besdrake.imitation import (
    DMP,
    MIN_IMITATED_EXECUTION_TIME,
    WEIGHTS_PER_JOINT,
    DMPParameterError,
    DMPParameterization,
)
from besdrake.plan import MotionPlan
from test_dmp_helpers import throw_demo


@pytest.fixture()
def param() -> DMPParameterization:
    t, q = throw_demo()
    return DMPParameterization(DMP(6, WEIGHTS_PER_JOINT).fit(t, q))


def test_compi_throw_has_49_named_parameters(param: DMPParameterization) -> None:
    assert param.n_params == 49
    assert len(set(param.names)) == 49
    assert param.names[:2] == ("start.joint1", "start.joint2")
    assert param.names[6] == "goal.joint1"
    assert param.names[12] == "weight.joint1.0" and param.names[18] == "weight.joint2.0"
    assert param.names[-1] == "execution_time"
    assert MIN_IMITATED_EXECUTION_TIME == 0.95


def test_vector_roundtrip_and_template_untouched(param: DMPParameterization) -> None:
    theta = param.to_vector()
    assert theta[-1] == pytest.approx(param.template.execution_time)
    rng = np.random.default_rng(2)
    theta2 = theta + rng.normal(0.0, 0.1, theta.size)
    dmp = param.from_vector(theta2)
    np.testing.assert_array_equal(param.to_vector(dmp), theta2)
    np.testing.assert_array_equal(param.to_vector(), theta)  # template unchanged
    np.testing.assert_array_equal(dmp.goal_velocity, param.template.goal_velocity)  # kept from imitation


def test_motion_plan_is_the_rollout(param: DMPParameterization) -> None:
    theta = param.to_vector()
    theta[-1] = 1.4
    theta[6] += 0.2  # goal of joint1
    plan = param.motion_plan(theta, dt=0.002)
    assert isinstance(plan, MotionPlan)
    plan.validate()
    assert plan.t[-1] == pytest.approx(1.4)
    assert plan.q.shape == (701, 6) and plan.qd.shape == (701, 6)
    ref = param.from_vector(theta).open_loop(0.002)
    np.testing.assert_array_equal(plan.q, ref.y)
    np.testing.assert_array_equal(plan.qd, ref.yd)
    assert abs(plan.q[-1, 0] - theta[6]) < 0.02
    longer = param.motion_plan(theta, dt=0.002, run_time=1.6)
    assert longer.t[-1] == pytest.approx(1.6)


@pytest.mark.parametrize(
    ("index", "value", "match"),
    [(3, np.nan, "start.joint4"), (20, np.inf, "weight.joint2.2"), (48, 0.0, "execution_time"), (48, -0.5, "execution_time")],
)
def test_bad_parameters_raise_naming_the_entry(param: DMPParameterization, index: int, value: float, match: str) -> None:
    theta = param.to_vector()
    theta[index] = value
    with pytest.raises(DMPParameterError, match=match):
        param.from_vector(theta)
    with pytest.raises(ValueError):
        param.motion_plan(theta)


def test_wrong_length_raises(param: DMPParameterization) -> None:
    with pytest.raises(DMPParameterError, match="49"):
        param.from_vector(np.zeros(48))


def test_interpolated_plan_has_the_dmps_accelerations() -> None:
    """Sample velocities are consistent with the positions: the plan's cubic Hermite interpolation
    (what the simulation and its limit checks use) has the DMP's accelerations, not 2.5x them."""
    t = np.linspace(0.0, 1.2, 241)
    s = t / t[-1]
    q = np.column_stack([0.3 * s**2, 0.2 * np.sin(np.pi * s / 2), -0.3 * s**3, 0 * s, 0.4 * s**2, 0 * s])
    param = DMPParameterization(DMP(6, WEIGHTS_PER_JOINT).fit(t, q))
    plan = param.motion_plan(param.to_vector(), dt=0.002)
    fine_dmp = param.from_vector(param.to_vector())
    fine_dmp.int_dt = 1e-4
    fine = fine_dmp.open_loop(1e-4)
    true_acc = np.gradient(fine.yd, 1e-4, axis=0)
    times = np.arange(0.0, 1.2, 0.0005)
    plan_acc = plan.trajectory().derivative(2).vector_values(times).T
    ref = np.column_stack([np.interp(times, fine.t, true_acc[:, i]) for i in range(6)])
    peak = np.max(np.abs(ref))
    assert np.max(np.abs(plan_acc)) < 1.05 * peak
    assert np.max(np.abs(plan_acc - ref)) < 0.05 * peak


def test_a_parameterization_represents_only_dmps_of_its_own_template(param: DMPParameterization) -> None:
    """Throws refined from two imitated throws differ in their goal velocities, which theta does not hold: one
    parameterization stands for the other only as a different throw, so a search seeds with the first's kind alone."""
    from besdrake.imitation import shared_parameterization

    refined = param.from_vector(param.to_vector() + 0.05)
    assert param.represents(param.template) and param.represents(refined)
    other = param.template.copy()
    other.goal_velocity = other.goal_velocity + 0.3
    assert not param.represents(other)
    assert param.from_vector(param.to_vector(other)).to_dict() != other.to_dict()  # what the search would have thrown
    shared, kept = shared_parameterization([refined, other, param.template])
    assert kept == [0, 2] and shared.represents(refined)
    with pytest.raises(DMPParameterError):
        shared_parameterization([])
