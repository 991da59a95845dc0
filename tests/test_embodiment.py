"""Embodiment mapping: kinematic models, record mapping, synchronization frame, IK, scaling."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from besdrake.embodiment.ik import ik_trajectory
from besdrake.embodiment.kinematics import mount_to_transform, mounted_plant, welded_plant
from besdrake.embodiment.mapping import EmbodimentMapping
from besdrake.embodiment.record_mapping import HandTrajectory, RecordMappingError, hand_trajectory
from besdrake.embodiment.scaling import ease_in, temporal_scaling
from besdrake.embodiment.sync_frame import solve_sync_frame


from besdrake.robot import load_robot

COMPI = load_robot("compi")


@pytest.fixture(scope="module")
def welded():
    return welded_plant(COMPI)


@pytest.fixture(scope="module")
def mounted():
    return mounted_plant(COMPI)


@pytest.fixture(scope="module")
def throw_hand():
    """The first throw of synthetic subject 0, experiment 0, as hand poses in the back frame."""
    from besdrake.mocap.preprocess import preprocess
    from besdrake.tasks.throwing.demonstrator import SyntheticDemonstrator

    exp = SyntheticDemonstrator(0).subject(0).experiment(0)
    pre = preprocess(exp.recording, max_gap_s=3.0)
    seg = next(s for s in exp.segments if s.label == "throw")
    return hand_trajectory(pre, seg.start_frame, seg.end_frame)


def test_tcp_is_1174_mm_above_base_at_zero(welded):
    X = welded.tcp_pose(np.zeros(6))
    np.testing.assert_allclose(X.translation(), [0, 0, 0.158 + 0.28 + 0.34 + 0.346 + 0.05], atol=1e-9)


def test_mount_chain_places_the_base_where_mount_to_transform_says(welded, mounted):
    rng = np.random.default_rng(0)
    for _ in range(5):
        mount = rng.uniform(-0.5, 0.5, 6)
        q = rng.uniform(COMPI.position_limits[:, 0], COMPI.position_limits[:, 1])
        X_world_tcp = mounted.tcp_pose(q, mount)
        expected = mount_to_transform(mount) @ welded.tcp_pose(q)
        np.testing.assert_allclose(X_world_tcp.GetAsMatrix4(), expected.GetAsMatrix4(), atol=1e-9)


def _hand(n=10, **overrides):
    t = np.linspace(0, 0.3, n)
    fields = dict(
        t=t,
        position=np.zeros((n, 3)),
        quaternion=np.tile([1.0, 0, 0, 0], (n, 1)),
        palm_axis=np.tile([1.0, 0, 0], (n, 1)),
        frames=np.arange(n),
    )
    fields.update(overrides)
    return HandTrajectory(**fields)


def test_record_mapping_rejects_short_and_nan_segments():
    with pytest.raises(RecordMappingError, match="at least"):
        _hand(n=3)
    pos = np.zeros((10, 3))
    pos[4, 1] = np.nan
    with pytest.raises(RecordMappingError, match="NaN .*frame 4"):
        _hand(position=pos)


def test_hand_trajectory_rejects_frames_outside_the_recording(throw_hand):
    from besdrake.mocap.preprocess import preprocess
    from besdrake.tasks.throwing.demonstrator import SyntheticDemonstrator

    pre = preprocess(SyntheticDemonstrator(0).subject(0).experiment(0).recording, max_gap_s=3.0)
    with pytest.raises(RecordMappingError, match="outside"):
        hand_trajectory(pre, int(pre.frames[-1]) - 5, int(pre.frames[-1]) + 50)


def test_sync_frame_reaches_every_demonstrated_pose(throw_hand, mounted):
    result = solve_sync_frame(throw_hand.smoothed(), model=mounted)
    # Position boxes of +-0.5 mm per axis: at most 0.87 mm from the demonstrated point.
    assert result.position_residual.max() <= 1.0e-3
    assert np.all(result.q >= COMPI.position_limits[:, 0]) and np.all(result.q <= COMPI.position_limits[:, 1])
    assert np.abs(np.diff(result.q, axis=0)).max() < 0.5  # no jump between sampled poses
    # The frame is a proper rigid transform and its inverse.
    np.testing.assert_allclose(result.base_in_back @ result.back_in_base, np.eye(4), atol=1e-12)


def test_ik_reports_an_unreachable_pose_and_solves_the_others(welded):
    q_ref = np.array([[0.0, 0.4, 0.8, 0.0, 0.6, 0.0]] * 4) + np.linspace(0, 0.2, 4)[:, None]
    poses = [welded.tcp_pose(q) for q in q_ref]
    positions = np.array([X.translation() for X in poses])
    axes = np.array([X.rotation().matrix()[:, 2] for X in poses])
    positions[2] = [3.0, 0.0, 0.5]  # 3 m away: beyond COMPI's 1.17 m reach
    ik = ik_trajectory(welded, np.arange(4) * 0.01, positions, axes, q_ref)
    assert ik.reachable.tolist() == [True, True, False, True]
    assert ik.position_residual[2] > 1.5
    assert np.all(np.delete(ik.position_residual, 2) < 1e-3)
    assert ik.unreachable_report()[0]["index"] == 2


def test_temporal_scaling_matches_the_analytic_factor():
    t = np.linspace(0, 1.0, 2001)
    amp, omega = 0.5, 2 * np.pi * 2.0  # peak velocity 6.28 rad/s, acceleration 79.0 rad/s^2
    q = np.zeros((len(t), 6))
    q[:, 1] = amp * np.sin(omega * t)
    limits = dataclasses.replace(COMPI.limits, velocity=np.full(6, 3.14), acceleration=np.full(6, 15.0))  # factors 2.00, 2.29
    result = temporal_scaling(t, q, limits, safety=1.0, min_duration=0.5)
    expected = np.sqrt(amp * omega**2 / 15.0)
    assert result.factor == pytest.approx(expected, rel=1e-3)
    assert result.limiting == "acceleration"
    slow = temporal_scaling(t, q * 1e-3, limits, safety=1.0, min_duration=2.0)
    assert slow.limiting == "minimum execution time" and slow.duration == pytest.approx(2.0)


def test_ease_in_starts_at_rest_and_joins_with_the_demonstrated_velocity():
    t = np.linspace(0, 0.3, 31)
    v0 = np.array([1.0, -2.0, 0, 0, 0, 3.0])
    q = np.outer(t, v0)  # constant velocity from the first sample
    t2, q2 = ease_in(t, q, 0.05)
    dt = t2[1] - t2[0]
    n_run = len(t2) - len(t)
    assert np.all(np.diff(t2) > 0) and t2[0] == 0.0
    # Constant acceleration v0 / 0.05 from rest: the first step covers a / 2 * dt^2.
    np.testing.assert_allclose(q2[1] - q2[0], 0.5 * (v0 / 0.05) * dt**2, atol=1e-12)
    # Position and velocity are continuous where the run-up meets the demonstration.
    np.testing.assert_allclose(q2[n_run], q[0], atol=1e-12)
    np.testing.assert_allclose((q2[n_run] - q2[n_run - 1]) / dt, v0, rtol=0.11)


def test_imitating_a_synthetic_throw_gives_an_executable_49_parameter_plan(throw_hand, tmp_path):
    mapping = EmbodimentMapping(COMPI)
    result = mapping.imitate(throw_hand, name="s0e0t0")
    assert result.theta.shape == (49,)
    assert result.executable, result.summary()
    assert result.plan.check_limits(COMPI.limits).ok
    assert result.dmp.execution_time >= 0.95
    # The plan reproduces the IK joint path: start and goal are the first and last IK samples.
    np.testing.assert_allclose(result.plan.q[-1], result.ik.q[-1], atol=0.05)
    summary = json.loads(json.dumps(result.summary()))
    assert summary["ik_max_position_residual_m"] <= 1e-3
    path = result.save(tmp_path)
    saved = json.loads(path.read_text())
    assert len(saved["theta"]) == 49 and saved["theta_names"][-1] == "execution_time"
    assert (tmp_path / "s0e0t0.plan.json").is_file()


def test_jump_detector_flags_a_branch_switch_but_not_a_fast_smooth_motion():
    from besdrake.embodiment.ik import IKTrajectory

    t = np.linspace(0, 0.3, 31)
    q = np.zeros((31, 6))
    q[:, 1] = 2.0 * np.sin(np.pi * t / 0.3) ** 2  # fast: steps up to 0.2 rad at 100 Hz
    ones = np.ones(31, dtype=bool)
    smooth = IKTrajectory(t, q, np.zeros(31), np.zeros(31), ones)
    assert smooth.jumps() == []
    flipped = q.copy()
    flipped[16:, 3] += np.pi  # the forearm flips to the other IK branch
    jumps = IKTrajectory(t, flipped, np.zeros(31), np.zeros(31), ones).jumps()
    assert [(i, j) for i, j, _ in jumps] == [(15, 3)]


def test_within_cone_turns_only_axes_outside_the_cone_towards_up():
    from besdrake.embodiment.mapping import within_cone

    up = np.array([0.0, 0.0, 1.0])
    angles = np.radians([0.0, 20.0, 34.9, 60.0, 95.0, 180.0])
    axes = np.stack([np.sin(angles), np.zeros_like(angles), np.cos(angles)], axis=1)
    out = within_cone(axes, up, np.radians(35.0))
    got = np.degrees(np.arccos(np.clip(out @ up, -1, 1)))
    np.testing.assert_allclose(got, [0.0, 20.0, 34.9, 35.0, 35.0, 35.0], atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0)
    assert np.all(out[3:5, 0] > 0) and np.allclose(out[:5, 1], 0.0)  # turned in their own vertical plane (180 deg: any)


def test_imitated_throw_holds_the_ball_within_the_cone(throw_hand, welded):
    """The task constraint of throwing: the scoop opening stays near vertical in the imitated throw (the
    palm's axis alone tilts the scoop ~90 degrees, so the ball falls out at once)."""
    from besdrake.embodiment.mapping import ImitationOptions

    def tilts(q):
        return np.degrees([np.arccos(np.clip(welded.tcp_pose(x).rotation().matrix()[2, 2], -1, 1)) for x in q[::10]])

    held = EmbodimentMapping(COMPI, ImitationOptions(hold_cone_deg=35.0)).imitate(throw_hand)
    free = EmbodimentMapping(COMPI, ImitationOptions(hold_cone_deg=None)).imitate(throw_hand)
    assert held.executable and tilts(held.ik.q).max() <= 35.0 + 3.0
    assert tilts(free.ik.q).max() > 60.0
