"""Drake adapters: PiecewisePolynomial for a TrajectorySource, and the DmpSource LeafSystem."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import TrajectorySource, VectorLogSink

from besdrake.imitation import DMP
from besdrake.imitation.drake import DmpSource, dmp_piecewise_polynomial, to_piecewise_polynomial
from test_dmp_helpers import throw_demo


@pytest.fixture(scope="module")
def dmp() -> DMP:
    t, q = throw_demo()
    return DMP(6, 6).fit(t, q)


def test_piecewise_polynomial_interpolates_rollout(dmp: DMP) -> None:
    traj = dmp.open_loop(0.01)
    pp = to_piecewise_polynomial(traj)
    assert pp.rows() == 6 and pp.end_time() == pytest.approx(traj.t[-1])
    np.testing.assert_allclose(pp.vector_values(traj.t).T, traj.y, atol=1e-12)
    np.testing.assert_allclose(pp.derivative(1).vector_values(traj.t).T, traj.yd, atol=1e-9)
    # Between knots it stays close to a fine rollout.
    fine = dmp.open_loop(0.001)
    np.testing.assert_allclose(pp.vector_values(fine.t).T, fine.y, atol=1e-4)


def test_trajectory_source_in_a_diagram(dmp: DMP) -> None:
    builder = DiagramBuilder()
    source = builder.AddSystem(TrajectorySource(dmp_piecewise_polynomial(dmp, 0.01), output_derivative_order=1))
    sink = builder.AddSystem(VectorLogSink(12, publish_period=0.05))
    builder.Connect(source.get_output_port(), sink.get_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(dmp.execution_time)
    log = sink.FindLog(simulator.get_context())
    ref = dmp.open_loop(0.05)
    n = min(log.data().shape[1], ref.t.size)
    np.testing.assert_allclose(log.sample_times()[:n], ref.t[:n], atol=1e-9)
    np.testing.assert_allclose(log.data()[:6, :n].T, ref.y[:n], atol=1e-4)


@pytest.mark.parametrize("start_time", [0.0, 0.25])
def test_dmp_source_equals_open_loop(dmp: DMP, start_time: float) -> None:
    dt = 0.01
    system = DmpSource(dmp, dt=dt, start_time=start_time)
    context = system.CreateDefaultContext()
    simulator = Simulator(system, context)
    simulator.Initialize()
    ref = dmp.open_loop(dt, run_time=dmp.execution_time + 0.1)
    if start_time > 0:
        simulator.AdvanceTo(start_time / 2)
        np.testing.assert_array_equal(system.GetOutputPort("position").Eval(context), dmp.start)
        np.testing.assert_array_equal(system.GetOutputPort("velocity").Eval(context), dmp.start_velocity)
    for k in range(0, ref.t.size, 7):
        simulator.AdvanceTo(start_time + ref.t[k] + dt / 2)  # inside the hold interval of sample k
        np.testing.assert_allclose(system.GetOutputPort("position").Eval(context), ref.y[k], atol=1e-9)
        np.testing.assert_allclose(system.GetOutputPort("velocity").Eval(context), ref.yd[k], atol=1e-7)
        state = system.GetOutputPort("state").Eval(context)
        np.testing.assert_allclose(state, np.concatenate((ref.y[k], ref.yd[k])), atol=1e-7)


def test_dmp_source_copies_the_dmp(dmp: DMP) -> None:
    mine = dmp.copy()
    system = DmpSource(mine, dt=0.01)
    mine.goal = mine.goal + 1.0
    np.testing.assert_array_equal(system.dmp.goal, dmp.goal)


def test_dmp_source_goal_input_adapts_online(dmp: DMP) -> None:
    from pydrake.systems.primitives import ConstantVectorSource

    new_goal = dmp.goal + np.linspace(-0.3, 0.3, 6)
    builder = DiagramBuilder()
    source = builder.AddSystem(DmpSource(dmp, dt=0.01))
    goal = builder.AddSystem(ConstantVectorSource(new_goal))
    builder.Connect(goal.get_output_port(), source.GetInputPort("goal"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(dmp.execution_time + 0.005)
    adapted = dmp.copy()
    adapted.goal = new_goal
    expected = adapted.open_loop(0.01).y[-1]
    context = source.GetMyContextFromRoot(simulator.get_context())
    np.testing.assert_allclose(source.GetOutputPort("position").Eval(context), expected, atol=1e-9)
    assert np.max(np.abs(expected - new_goal)) < 0.02
