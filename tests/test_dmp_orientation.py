"""Quaternion orientation DMP (Ude et al. 2014): oracle agreement, rotations beyond pi, double cover."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from besdrake.imitation import DMPParameterError, QuaternionDMP
from besdrake.imitation import quaternion as quat
from test_dmp_helpers import oracle


def _angle_between(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Rotation angle (rad, in [0, pi]) between orientations, ignoring the quaternion sign."""
    return 2.0 * np.arccos(np.clip(np.abs(np.sum(p * q, axis=-1)), 0.0, 1.0))


def _demo(total_angle: float, duration: float = 1.2, n: int = 241) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-jerk turn by ``total_angle`` about a tilted axis, with a wobble; at rest at both ends
    (the orientation DMP starts at rest)."""
    t = np.linspace(0.0, duration, n)
    s = t / duration
    progress = 10 * s**3 - 15 * s**4 + 6 * s**5
    axis = np.array([0.2, -0.3, 0.93])
    axis /= np.linalg.norm(axis)
    wobble = 0.3 * np.sin(np.pi * s)[:, None] ** 2 * np.array([1.0, 0.0, 0.0])
    r = total_angle * progress[:, None] * axis
    q = quat.multiply(quat.from_rotation_vector(r), quat.from_rotation_vector(wobble))
    return t, quat.multiply(q, quat.from_rotation_vector(np.array([0.3, 0.1, -0.2])))


def _oracle_rollout(dmp: QuaternionDMP, dt: float) -> np.ndarray:
    """The compiled quaternion step of movement_primitives (wrapped log) with our weights."""
    mp = oracle()
    from movement_primitives import dmp_fast
    from movement_primitives.dmp._forcing_term import ForcingTerm

    tau = dmp.execution_time
    forcing = ForcingTerm(3, dmp.n_weights_per_dim, tau, 0.0, 0.8, -np.log(0.01))
    forcing.weights_[:, :] = dmp.weights
    assert mp is not None
    times = np.arange(0.0, tau + dt, dt)
    y, yd = dmp.start, np.zeros(3)
    out = [y.copy()]
    zeros = np.zeros(3)
    for k in range(1, times.size):
        dmp_fast.dmp_step_quaternion(
            times[k - 1], times[k], y, yd, dmp.goal, zeros, zeros, dmp.start, zeros, zeros, tau, 0.0,
            dmp.alpha_y, dmp.beta_y, forcing, int_dt=dmp.int_dt,
        )
        out.append(y.copy())
    return np.array(out)


def test_quaternion_helpers_match_scipy() -> None:
    rng = np.random.default_rng(0)
    r = rng.normal(size=(200, 3))
    q = quat.from_rotation_vector(r)
    ref = Rotation.from_rotvec(r).as_quat(scalar_first=True)
    np.testing.assert_allclose(np.abs(np.sum(q * ref, axis=1)), 1.0, atol=1e-12)
    p = quat.from_rotation_vector(rng.normal(size=(200, 3)))
    prod = quat.multiply(p, q)
    ref_prod = (Rotation.from_quat(p, scalar_first=True) * Rotation.from_quat(q, scalar_first=True)).as_quat(scalar_first=True)
    np.testing.assert_allclose(np.abs(np.sum(prod * ref_prod, axis=1)), 1.0, atol=1e-12)
    short = np.linalg.norm(r, axis=1) < 2 * np.pi
    np.testing.assert_allclose(quat.rotation_vector(q[short]), r[short], atol=1e-12)


def test_log_does_not_wrap_beyond_pi() -> None:
    turn = quat.from_rotation_vector(np.array([0.0, 0.0, 1.5 * np.pi]))
    np.testing.assert_allclose(quat.rotation_vector(turn), [0.0, 0.0, 1.5 * np.pi], atol=1e-12)
    # The same orientation as a rotation (SO(3)) is the short way round: what a wrapped log returns.
    np.testing.assert_allclose(Rotation.from_quat(turn, scalar_first=True).as_rotvec(), [0.0, 0.0, -0.5 * np.pi], atol=1e-12)
    np.testing.assert_allclose(quat.rotation_vector(-turn), [0.0, 0.0, -0.5 * np.pi], atol=1e-12)


@pytest.mark.parametrize("dt", [0.01, 0.001])
def test_rollout_agrees_with_oracle_below_pi(dt: float) -> None:
    t, q = _demo(0.6 * np.pi)
    dmp = QuaternionDMP(8).fit(t, q)
    ours = dmp.open_loop(dt).q
    theirs = _oracle_rollout(dmp, dt)
    assert ours.shape == theirs.shape
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-8)


def test_imitation_agrees_with_oracle_below_pi() -> None:
    """Oracle: movement_primitives' CartesianDMP (pytransform3d, or its scipy stand-in, see helpers)."""
    mp = oracle()
    t, q = _demo(0.6 * np.pi)
    o = mp.CartesianDMP(execution_time=t[-1], dt=0.01, n_weights_per_dim=8)
    poses = np.hstack((np.zeros((t.size, 3)), q))
    o.imitate(t, poses)
    _, oracle_poses = o.open_loop()
    dmp = QuaternionDMP(8).fit(t, q)
    w = o.forcing_term_rot.weights_
    assert np.max(np.abs(dmp.weights - w)) <= 1e-8 * max(1.0, np.max(np.abs(w)))
    ours = dmp.open_loop(0.01).q
    assert ours.shape == oracle_poses[:, 3:].shape
    np.testing.assert_allclose(ours, oracle_poses[:, 3:], rtol=0, atol=1e-8)


def test_imitation_reproduces_demonstration_and_reaches_goal() -> None:
    t, q = _demo(0.6 * np.pi)
    dmp = QuaternionDMP(10).fit(t, q)
    traj = dmp.open_loop(t[1] - t[0])
    assert np.max(_angle_between(traj.q, q)) < 0.02
    assert _angle_between(traj.q[-1], q[-1]) < 0.01
    np.testing.assert_allclose(np.linalg.norm(traj.q, axis=1), 1.0, atol=1e-9)


def test_rotation_beyond_pi_follows_the_demonstration() -> None:
    t, q = _demo(1.5 * np.pi)
    dmp = QuaternionDMP(10).fit(t, q)
    # The start-to-goal rotation is 270 degrees (plus the wobble), kept by the goal's sign.
    assert np.linalg.norm(quat.rotation_vector(quat.multiply(dmp.goal, quat.conjugate(dmp.start)))) > np.pi
    traj = dmp.open_loop(t[1] - t[0])
    assert np.max(_angle_between(traj.q, q)) < 0.03
    assert _angle_between(traj.q[-1], q[-1]) < 0.01
    # A log that wraps to [0, pi] (the oracle's) turns the short way and leaves the demonstration.
    wrapped = _oracle_rollout(dmp, t[1] - t[0])
    assert np.max(_angle_between(wrapped, q)) > 1.0


def test_double_cover_signs_do_not_matter() -> None:
    t, q = _demo(1.2 * np.pi)
    rng = np.random.default_rng(5)
    flipped = q * rng.choice([-1.0, 1.0], size=(q.shape[0], 1))
    a = QuaternionDMP(8).fit(t, q)
    b = QuaternionDMP(8).fit(t, flipped)
    np.testing.assert_allclose(b.weights, a.weights, atol=1e-9 * np.max(np.abs(a.weights)))
    ta, tb = a.open_loop(0.01), b.open_loop(0.01)
    np.testing.assert_allclose(_angle_between(ta.q, tb.q), 0.0, atol=1e-6)
    # Assigning the goal with the other sign keeps the turning direction.
    c = a.copy()
    c.goal = -a.goal
    np.testing.assert_allclose(c.goal, a.goal)
    np.testing.assert_allclose(c.open_loop(0.01).q, ta.q, atol=1e-12)
    # Choosing the other sign explicitly turns the other way round (the short way, 0.8 pi).
    c.set_start_and_goal(a.start, -a.goal)
    other = c.open_loop(0.01).q
    assert _angle_between(other[-1], ta.q[-1]) < 0.05
    assert np.max(_angle_between(other, ta.q)) > 1.0


def test_single_steps_equal_open_loop() -> None:
    t, q = _demo(1.5 * np.pi)
    dmp = QuaternionDMP(8).fit(t, q)
    traj = dmp.open_loop(0.01)
    y, w = dmp.start, np.zeros(3)
    for k in range(1, traj.t.size):
        y, w = dmp.step(traj.t[k - 1], y, w, 0.01)
        np.testing.assert_allclose(y, traj.q[k], atol=1e-12)
        np.testing.assert_allclose(w, traj.omega[k], atol=1e-10)


def test_invalid_orientations_raise() -> None:
    dmp = QuaternionDMP(6)
    with pytest.raises(DMPParameterError, match="unit quaternion"):
        dmp.goal = [2.0, 0.0, 0.0, 0.0]
    with pytest.raises(DMPParameterError, match="NaN"):
        dmp.start = [np.nan, 0.0, 0.0, 1.0]
    t, q = _demo(1.0)
    q[3] = 0.0
    with pytest.raises(DMPParameterError, match="unit quaternion"):
        dmp.fit(t, q)


def test_zero_weights_turn_beyond_pi_the_long_way_to_the_goal() -> None:
    dmp = QuaternionDMP(6, execution_time=1.0)
    axis = np.array([0.0, 0.6, 0.8])
    dmp.set_start_and_goal([1.0, 0.0, 0.0, 0.0], quat.from_rotation_vector(1.6 * np.pi * axis))
    traj = dmp.open_loop(0.01, run_time=2.0)
    turned = quat.rotation_vector(quat.multiply(traj.q, quat.conjugate(dmp.start)))
    progress = turned @ axis  # angle turned about the axis, rad
    np.testing.assert_allclose(np.cross(turned, axis), 0.0, atol=1e-9)  # stays on the geodesic
    assert np.all(np.diff(progress) >= -1e-12)  # monotonic, no overshoot (critically damped)
    assert progress[-1] == pytest.approx(1.6 * np.pi, abs=0.02)
