"""Joint-space DMP with goal velocity: agreement with the movement_primitives oracle and properties."""

from __future__ import annotations

import json

import numpy as np
import pytest

from besdrake.imitation import DMP, DMPParameterError
from test_dmp_helpers import oracle, throw_demo


def _oracle_dmp(dmp: DMP, dt: float):
    mp = oracle()
    o = mp.DMPWithFinalVelocity(
        dmp.n_dims, execution_time=dmp.execution_time, dt=dt, n_weights_per_dim=dmp.n_weights_per_dim,
        int_dt=dmp.int_dt, alpha_y=dmp.alpha_y, beta_y=dmp.beta_y,
    )
    o.set_weights(dmp.get_weights())
    o.configure(
        start_y=dmp.start.copy(), start_yd=dmp.start_velocity.copy(), start_ydd=dmp.start_acceleration.copy(),
        goal_y=dmp.goal.copy(), goal_yd=dmp.goal_velocity.copy(), goal_ydd=dmp.goal_acceleration.copy(),
    )
    return o


@pytest.mark.parametrize(
    ("duration", "dt", "n_weights"), [(1.0, 0.01, 10), (1.5, 0.001, 6), (0.95, 0.001, 6), (2.5, 0.01, 8)]
)
def test_imitation_and_rollout_agree_with_oracle(duration: float, dt: float, n_weights: int) -> None:
    t, q = throw_demo(duration)
    mp = oracle()
    o = mp.DMPWithFinalVelocity(6, execution_time=duration, dt=dt, n_weights_per_dim=n_weights)
    o.imitate(t, q)
    t_o, y_o = o.open_loop()

    dmp = DMP(6, n_weights).fit(t, q)
    traj = dmp.open_loop(dt)

    w_o = o.forcing_term.weights_
    assert np.max(np.abs(dmp.weights - w_o)) <= 1e-8 * max(1.0, np.max(np.abs(w_o)))
    np.testing.assert_allclose(dmp.goal_velocity, o.goal_yd, atol=1e-8)
    np.testing.assert_allclose(dmp.goal_acceleration, o.goal_ydd, atol=1e-8)
    assert traj.t.shape == t_o.shape
    np.testing.assert_allclose(traj.t, t_o, atol=1e-12)
    np.testing.assert_allclose(traj.y, y_o, rtol=0, atol=1e-8)


def test_meta_parameters_and_long_runs_agree_with_oracle() -> None:
    rng = np.random.default_rng(3)
    dmp = DMP(6, 6, execution_time=1.2)
    dmp.start = rng.uniform(-1, 1, 6)
    dmp.goal = rng.uniform(-1, 1, 6)
    dmp.goal_velocity = rng.uniform(-2, 2, 6)
    dmp.set_weights(rng.normal(0.0, 100.0, dmp.n_weights))
    for tau in (0.95, 1.2, 2.5):
        dmp.execution_time = tau
        _, y_o = _oracle_dmp(dmp, 0.001).open_loop(run_t=tau + 0.3)  # also beyond the execution time
        traj = dmp.open_loop(0.001, tau + 0.3)
        np.testing.assert_allclose(traj.y, y_o, rtol=0, atol=1e-8)


def test_zero_weights_reach_goal_and_goal_velocity() -> None:
    dmp = DMP(6, 6, execution_time=1.2)
    dmp.start = np.linspace(-1, 1, 6)
    dmp.goal = np.linspace(0.5, -0.5, 6)
    dmp.goal_velocity = np.linspace(-2, 2, 6)
    traj = dmp.open_loop(0.001)
    assert traj.t[-1] == pytest.approx(1.2)
    # Without forcing term the DMP tracks the moving goal; what is left is the Euler error (int_dt=1 ms).
    assert np.max(np.abs(traj.y[-1] - dmp.goal)) < 5e-3
    assert np.max(np.abs(traj.yd[-1] - dmp.goal_velocity)) < 5e-3
    finer = dmp.copy()
    finer.int_dt = 1e-4
    fine = finer.open_loop(0.001)
    assert np.max(np.abs(fine.yd[-1] - dmp.goal_velocity)) < 5e-4  # first-order convergence


def test_imitation_reproduces_demonstration_and_final_velocity() -> None:
    t, q = throw_demo()
    dmp = DMP(6, 10).fit(t, q)
    traj = dmp.open_loop(t[1] - t[0])
    assert np.max(np.abs(traj.y - q)) < 0.02
    demo_final_velocity = (q[-1] - q[-2]) / (t[-1] - t[-2])
    np.testing.assert_allclose(dmp.goal_velocity, demo_final_velocity)
    assert np.max(np.abs(traj.yd[-1] - demo_final_velocity)) < 0.05 * np.max(np.abs(demo_final_velocity))


def test_demonstration_time_offset_does_not_matter() -> None:
    t, q = throw_demo()
    a = DMP(6, 6).fit(t, q)
    b = DMP(6, 6).fit(t + 12.5, q)
    assert b.execution_time == pytest.approx(a.execution_time)
    np.testing.assert_allclose(b.weights, a.weights, rtol=1e-6, atol=1e-6 * np.max(np.abs(a.weights)))


@pytest.mark.parametrize(("dt", "int_dt"), [(0.001, 0.001), (0.01, 0.001), (0.004, 0.003)])
def test_single_steps_equal_open_loop(dt: float, int_dt: float) -> None:
    t, q = throw_demo()
    dmp = DMP(6, 6, int_dt=int_dt).fit(t, q)
    traj = dmp.open_loop(dt, run_time=dmp.execution_time + 0.2)
    y, yd = dmp.start_state(dt)
    np.testing.assert_array_equal(y, traj.y[0])
    np.testing.assert_array_equal(yd, traj.yd[0])
    for k in range(1, traj.t.size):
        y, yd = dmp.step(traj.t[k - 1], y, yd, dt)
        np.testing.assert_allclose(y, traj.y[k], rtol=0, atol=1e-9)
        np.testing.assert_allclose(yd, traj.yd[k], rtol=0, atol=1e-7)


def test_uneven_step_split_stays_close_to_fine_integration() -> None:
    t, q = throw_demo()
    dmp = DMP(6, 6, int_dt=0.003).fit(t, q)
    coarse = dmp.open_loop(0.004)  # 2 sub-steps of 2 ms
    fine = dmp.copy()
    fine.int_dt = 1e-4
    reference = fine.open_loop(0.004)
    assert np.max(np.abs(coarse.y - reference.y)) < 0.01


def test_temporal_scaling_keeps_shape_and_final_velocity() -> None:
    rng = np.random.default_rng(7)
    dmp = DMP(6, 6, execution_time=1.0)
    dmp.start = rng.uniform(-1, 1, 6)
    dmp.goal = rng.uniform(-1, 1, 6)
    dmp.set_weights(rng.normal(0.0, 50.0, dmp.n_weights))
    slow = dmp.copy()
    slow.execution_time = 2.0
    # Goal velocity zero: the same path in normalised time (up to the Euler error).
    a, b = dmp.open_loop(0.001), slow.open_loop(0.001)
    assert np.max(np.abs(a.y - b.y[::2])) < 5e-3
    # With a goal velocity: every execution time ends with (about) that velocity.
    # The velocity error left at the end is the imitation residual of the forcing term, fixed in
    # normalised time, so in rad/s it shrinks as 1/tau; plus the Euler error (< 0.01 rad/s at 1 ms).
    t, q = throw_demo()
    imitated = DMP(6, 6).fit(t, q)
    v = imitated.goal_velocity
    error_at_demo_speed = np.max(np.abs(imitated.open_loop(0.001).yd[-1] - v))
    assert error_at_demo_speed < 0.05 * np.max(np.abs(v))
    for factor in (0.5, 0.75, 1.5, 2.0, 4.0):
        scaled = imitated.copy()
        scaled.execution_time = factor * imitated.execution_time
        traj = scaled.open_loop(0.001)
        assert traj.t[-1] == pytest.approx(scaled.execution_time)
        assert np.max(np.abs(traj.yd[-1] - v)) < error_at_demo_speed / factor + 0.01
        assert np.max(np.abs(traj.y[-1] - imitated.goal)) < 0.01


def test_weights_get_set_roundtrip() -> None:
    dmp = DMP(6, 6)
    w = np.arange(36.0)
    dmp.set_weights(w)
    np.testing.assert_array_equal(dmp.get_weights(), w)
    np.testing.assert_array_equal(dmp.weights[1], np.arange(6.0, 12.0))  # joint-major
    dmp.get_weights()[0] = 99.0  # a copy
    assert dmp.weights[0, 0] == 0.0


@pytest.mark.parametrize(
    ("name", "value"),
    [("start", [np.nan] * 6), ("goal", np.ones(5)), ("goal_velocity", [np.inf] * 6),
     ("execution_time", 0.0), ("execution_time", -1.0), ("execution_time", np.nan), ("weights", np.full((6, 6), np.nan)),
     ("int_dt", 0.0), ("alpha_y", -25.0), ("beta_y", [1.0, 2.0])],
)
def test_invalid_meta_parameters_raise(name: str, value: object) -> None:
    dmp = DMP(6, 6)
    with pytest.raises(DMPParameterError, match=name):
        setattr(dmp, name, value)
    assert issubclass(DMPParameterError, ValueError)


def test_invalid_demonstrations_raise() -> None:
    t, q = throw_demo()
    bad = q.copy()
    bad[5, 2] = np.nan
    with pytest.raises(DMPParameterError, match="NaN"):
        DMP(6).fit(t, bad)
    with pytest.raises(DMPParameterError, match="increasing"):
        DMP(6).fit(t[::-1], q)
    with pytest.raises(DMPParameterError, match="dimensions"):
        DMP(5).fit(t, q)
    with pytest.raises(DMPParameterError, match="dt"):
        DMP(6).open_loop(dt=0.0)
    with pytest.raises(ValueError, match="weights per dimension"):
        DMP(6, n_weights_per_dim=1)
    with pytest.raises(DMPParameterError, match="sub-steps"):
        DMP(6).open_loop(dt=0.01, run_time=1e9)


def test_many_narrow_basis_functions_stay_finite() -> None:
    dmp = DMP(2, n_weights_per_dim=600)
    dmp.goal = [1.0, -1.0]
    dmp.set_weights(np.ones(dmp.n_weights))
    traj = dmp.open_loop(0.01, run_time=3.0)
    assert np.all(np.isfinite(traj.y))


def test_json_roundtrip_and_corrupt_file(tmp_path) -> None:
    t, q = throw_demo()
    dmp = DMP(6, 6).fit(t, q)
    path = tmp_path / "dmp.json"
    dmp.save(path)
    loaded = DMP.load(path)
    np.testing.assert_array_equal(loaded.open_loop(0.01).y, dmp.open_loop(0.01).y)
    path.write_text("{not json")
    with pytest.raises(DMPParameterError, match="not valid JSON"):
        DMP.load(path)
    data = dmp.to_dict()
    del data["goal"]
    path.write_text(json.dumps(data))
    with pytest.raises(DMPParameterError, match="goal"):
        DMP.load(path)


def test_rollout_never_ends_with_a_step_of_microseconds() -> None:
    """A run time just past a multiple of dt: the last sample moves to the run time (one step of dt + remainder from
    the sample before) instead of a step a controller cannot follow; a remainder of 0.1 dt or more keeps its own step."""
    from besdrake.imitation.dmp import MIN_LAST_STEP_FRACTION

    t, q = throw_demo()
    dmp = DMP(6, 6).fit(t, q)
    dt = 0.002
    for remainder in (9.4e-6, 0.5 * MIN_LAST_STEP_FRACTION * dt):
        dmp.execution_time = 600 * dt + remainder
        traj = dmp.open_loop(dt)
        assert traj.t[-1] == pytest.approx(dmp.execution_time, abs=1e-12) and len(traj.t) == 601
        assert traj.t[-1] - traj.t[-2] == pytest.approx(dt + remainder)
        y, yd = dmp.step(traj.t[-2], traj.y[-2], traj.yd[-2], dt + remainder)
        np.testing.assert_allclose(y, traj.y[-1], atol=1e-12)
        fine = dmp.open_loop(dt / 4)  # the end state agrees with a finer rollout's (as the samples do: 2e-3 rad)
        assert fine.t[-1] == pytest.approx(traj.t[-1], abs=1e-12)
        np.testing.assert_allclose(traj.y[-1], fine.y[-1], atol=2e-3)
    dmp.execution_time = 600 * dt + 2 * MIN_LAST_STEP_FRACTION * dt
    traj = dmp.open_loop(dt)
    assert len(traj.t) == 602 and traj.t[-1] - traj.t[-2] == pytest.approx(2 * MIN_LAST_STEP_FRACTION * dt)


def test_rollout_ends_exactly_at_an_arbitrary_execution_time() -> None:
    t, q = throw_demo()
    dmp = DMP(6, 6).fit(t, q)
    dmp.execution_time = 1.2345  # policy search varies it continuously; not a multiple of dt
    traj = dmp.open_loop(0.002)
    assert traj.t[-1] == 1.2345
    assert np.all(np.diff(traj.t) > 0) and np.max(np.diff(traj.t)) == pytest.approx(0.002)
    assert np.max(np.abs(traj.yd[-1] - dmp.goal_velocity)) < 0.05 * np.max(np.abs(dmp.goal_velocity))
    y, yd = dmp.step(traj.t[-2], traj.y[-2], traj.yd[-2], traj.t[-1] - traj.t[-2])
    np.testing.assert_allclose(y, traj.y[-1], atol=1e-12)
    # Same path as a fine rollout at the shared sample times.
    fine = dmp.open_loop(0.0005)
    np.testing.assert_allclose(traj.y[:-1], fine.y[:-1:4], atol=2e-3)
