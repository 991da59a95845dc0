"""Preprocessing: gap filling, back frame, hand pose, velocities, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from besdrake.mocap.preprocess import (
    PreprocessError,
    back_frame,
    preprocess,
    rotation_to_quaternion,
    to_frame,
    velocity,
)
from besdrake.mocap.recording import MocapRecording

NAMES = ["Back top", "Back right", "Back left", "Hand top", "Hand right", "Hand left", "Elbow"]
# marker positions in the body (back) frame: x forward, y left, z up
LOCAL = np.array([
    [0.0, 0.0, 0.10], [0.0, -0.08, -0.05], [0.0, 0.08, -0.05],
    [0.40, -0.20, 0.30], [0.42, -0.24, 0.28], [0.42, -0.16, 0.28], [0.2, -0.25, 0.1],
])


def moving_body(n=200, freq=100.0, seed=0):
    """A rigid body rotating and translating: all markers fixed in its frame."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / freq
    rots = Rotation.from_rotvec(np.stack([0.3 * np.sin(t), 0.2 * t, 0.5 * np.cos(2 * t)], axis=1))
    origin = np.stack([t, 0.5 * np.sin(t), 1.0 + 0.1 * t], axis=1) + rng.normal(0, 0.0, (n, 3))
    centre = LOCAL[:3].mean(axis=0)
    pos = np.stack([rots.apply(LOCAL[j] - centre) + origin for j in range(len(LOCAL))], axis=1)
    return MocapRecording(NAMES, pos, freq), rots, origin


def test_back_frame_is_orthonormal_and_rigid_points_stay_fixed():
    rec, rots, origin = moving_body()
    pre = preprocess(rec)
    R = pre.back_rotation
    eye = np.einsum("nji,njk->nik", R, R)
    assert np.allclose(eye, np.eye(3), atol=1e-9)
    assert np.allclose(np.linalg.det(R), 1.0)
    # every marker is fixed in the body, so its back-frame coordinates are constant and equal LOCAL - centre
    centre = LOCAL[:3].mean(axis=0)
    assert np.allclose(pre.positions_back, (LOCAL - centre)[None], atol=1e-9)
    assert np.allclose(pre.hand_position_back, (LOCAL[3:6].mean(axis=0) - centre)[None], atol=1e-9)
    # hand orientation in the back frame is constant and unit
    q = pre.hand_orientation_back
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0)
    assert np.allclose(q, q[0], atol=1e-9)


def test_to_frame_inverts_the_pose():
    rng = np.random.default_rng(1)
    R = Rotation.random(5, random_state=2).as_matrix()
    o = rng.normal(size=(5, 3))
    local = rng.normal(size=(5, 3))
    world = np.einsum("nij,nj->ni", R, local) + o
    assert np.allclose(to_frame(world, o, R), local)


def test_quaternions_are_sign_continuous_and_match_scipy():
    rots = Rotation.from_rotvec(np.linspace(0, 6.0, 100)[:, None] * np.array([0, 0, 1.0]))
    q = rotation_to_quaternion(rots.as_matrix())
    assert np.all(np.sum(q[1:] * q[:-1], axis=1) > 0)  # no flips along a continuous rotation
    back = Rotation.from_quat(q[:, [1, 2, 3, 0]])
    assert np.allclose((back.inv() * rots).magnitude(), 0.0, atol=1e-9)


def test_velocity_of_a_ramp_and_a_sine():
    f = 100.0
    t = np.arange(300) / f
    x = np.stack([2.0 * t, np.sin(t)], axis=1)
    v = velocity(x, f)
    assert np.allclose(v[:, 0], 2.0, atol=1e-9)
    assert np.allclose(v[5:-5, 1], np.cos(t[5:-5]), atol=2e-3)


def test_preprocess_fills_short_gaps_and_refuses_long_ones():
    rec, _, _ = moving_body(n=400)
    truth = rec.positions.copy()
    hand = NAMES.index("Hand top")
    rec.positions[100:110, hand] = np.nan  # 0.1 s: filled
    pre = preprocess(rec, max_gap_s=0.25)
    assert pre.interpolated[100:110, hand].all() and pre.interpolated[:, hand].sum() == 10
    assert np.allclose(pre.positions[100:110, hand], truth[100:110, hand], atol=1e-3)
    rec.positions[200:260, hand] = np.nan  # 0.6 s: too long for a hand marker
    with pytest.raises(PreprocessError, match="Hand top"):
        preprocess(rec, max_gap_s=0.25)


def test_preprocess_flags_filled_hand_samples():
    rec, _, _ = moving_body()
    rec.positions[50:55, NAMES.index("Hand top")] = np.nan
    pre = preprocess(rec)
    assert pre.interpolated[50:55, NAMES.index("Hand top")].all()
    assert any("Hand top" in w for w in pre.warnings)
    assert np.isfinite(pre.hand_velocity).all()


def test_marker_never_visible_is_a_clear_error():
    rec, _, _ = moving_body()
    rec.positions[:, NAMES.index("Back left")] = np.nan
    with pytest.raises(PreprocessError, match="Back left.*never visible"):
        preprocess(rec)


def test_absent_marker_is_a_clear_error():
    rec, _, _ = moving_body()
    rec = rec.select(["Back top", "Back right", "Back left", "Hand top"])
    with pytest.raises(PreprocessError, match="Hand right"):
        preprocess(rec)


def test_long_gap_in_a_needed_marker_names_the_frames():
    rec, _, _ = moving_body()
    rec.positions[80:150, NAMES.index("Hand left")] = np.nan
    with pytest.raises(PreprocessError, match=r"Hand left.*frame"):
        preprocess(rec)


def test_too_short_recording():
    rec, _, _ = moving_body(n=2)
    with pytest.raises(PreprocessError, match="at least 3"):
        preprocess(rec)


def test_real_recording(shared_data):
    from besdrake.mocap.qualisys import read_tsv

    rec = read_tsv(shared_data / "pick_and_place" / "subject1_run1.tsv")
    pre = preprocess(rec)
    speed = np.linalg.norm(pre.hand_velocity, axis=1)
    assert 0.5 < speed.max() < 5.0  # m/s: a human hand
    assert np.isfinite(pre.hand_position_back).all()
    # the back markers sit near the back-frame origin, the hand well away from it
    assert np.linalg.norm(pre.marker_back("Back top"), axis=1).max() < 0.3
    assert np.linalg.norm(pre.hand_position_back, axis=1).mean() > 0.3
