"""Cartesian DMP = position DMP with goal velocity + quaternion orientation DMP."""

from __future__ import annotations

import numpy as np
import pytest

from besdrake.imitation import DMP, CartesianDMP, DMPParameterError, QuaternionDMP
from test_dmp_helpers import oracle
from test_dmp_orientation import _angle_between, _demo


def _poses() -> tuple[np.ndarray, np.ndarray]:
    t, q = _demo(1.3 * np.pi)
    s = t / t[-1]
    p = np.column_stack((0.4 + 0.3 * s**2, -0.2 + 0.1 * np.sin(np.pi * s), 0.5 + 0.4 * s**3))
    return t, np.hstack((p, q))


def test_parts_equal_the_separate_dmps() -> None:
    t, poses = _poses()
    dmp = CartesianDMP(8).fit(t, poses)
    pos = DMP(3, 8).fit(t, poses[:, :3])
    rot = QuaternionDMP(8).fit(t, poses[:, 3:])
    traj = dmp.open_loop(0.01)
    np.testing.assert_array_equal(traj.pose[:, :3], pos.open_loop(0.01).y)
    np.testing.assert_array_equal(traj.pose[:, 3:], rot.open_loop(0.01).q)
    assert traj.velocity.shape == (traj.t.size, 6)


def test_position_part_agrees_with_oracle_goal_velocity_dmp() -> None:
    t, poses = _poses()
    mp = oracle()
    o = mp.DMPWithFinalVelocity(3, execution_time=t[-1], dt=0.01, n_weights_per_dim=8)
    o.imitate(t, poses[:, :3])
    _, y_o = o.open_loop()
    traj = CartesianDMP(8).fit(t, poses).open_loop(0.01)
    np.testing.assert_allclose(traj.pose[:, :3], y_o, rtol=0, atol=1e-8)


def test_reproduces_pose_and_final_linear_velocity() -> None:
    t, poses = _poses()
    dmp = CartesianDMP(10).fit(t, poses)
    traj = dmp.open_loop(t[1] - t[0])
    assert np.max(np.linalg.norm(traj.pose[:, :3] - poses[:, :3], axis=1)) < 0.01  # m
    assert np.max(_angle_between(traj.pose[:, 3:], poses[:, 3:])) < 0.03  # rad
    v_demo = (poses[-1, :3] - poses[-2, :3]) / (t[-1] - t[-2])
    assert np.linalg.norm(traj.velocity[-1, :3] - v_demo) < 0.05 * np.linalg.norm(v_demo)


def test_meta_parameters_weights_and_roundtrip() -> None:
    t, poses = _poses()
    dmp = CartesianDMP(6).fit(t, poses)
    assert dmp.n_weights == 36
    w = np.arange(36.0)
    dmp.set_weights(w)
    np.testing.assert_array_equal(dmp.get_weights(), w)
    dmp.execution_time = 2.0
    assert dmp.position.execution_time == dmp.orientation.execution_time == 2.0
    copy = CartesianDMP.from_dict(dmp.to_dict())
    np.testing.assert_array_equal(copy.open_loop(0.01).pose, dmp.open_loop(0.01).pose)
    rollout = dmp.open_loop(0.01)
    pose, vel = dmp.step(0.0, rollout.pose[0], rollout.velocity[0], 0.01)
    np.testing.assert_allclose(pose, rollout.pose[1], atol=1e-9)
    np.testing.assert_allclose(vel, rollout.velocity[1], atol=1e-7)
    with pytest.raises(DMPParameterError, match="7 columns"):
        CartesianDMP().fit(t, poses[:, :6])
    with pytest.raises(DMPParameterError, match="execution_time"):
        dmp.execution_time = -1.0


def test_save_and_load_any_dmp(tmp_path) -> None:
    from besdrake.imitation import load_dmp, save_dmp

    t, poses = _poses()
    for dmp in (CartesianDMP(6).fit(t, poses), DMP(3, 6).fit(t, poses[:, :3]), QuaternionDMP(6).fit(t, poses[:, 3:])):
        path = save_dmp(dmp, tmp_path / f"{type(dmp).__name__}.json")
        loaded = load_dmp(path)
        assert type(loaded) is type(dmp)
        np.testing.assert_array_equal(loaded.get_weights(), dmp.get_weights())
    (tmp_path / "bad.json").write_text('{"type": "Spline"}')
    with pytest.raises(DMPParameterError, match="does not describe a DMP"):
        load_dmp(tmp_path / "bad.json")
    with pytest.raises(DMPParameterError, match="not found"):
        load_dmp(tmp_path / "missing.json")
