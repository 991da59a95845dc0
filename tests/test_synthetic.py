"""The synthetic throwing demonstrator."""

from __future__ import annotations

import json

import numpy as np
import pytest

from besdrake.cli import main
from besdrake.tasks.throwing import arm_model as am
from besdrake.mocap.qualisys import Segment, read_segmentation, read_tsv, segmentation_path
from besdrake.tasks.throwing.demonstrator import (
    MARKER_NAMES,
    ExperimentTruth,
    SyntheticDemonstrator,
    generate_dataset,
    make_unlabeled,
)


@pytest.fixture(scope="module")
def experiment():
    return SyntheticDemonstrator(seed=3).subject(2).experiment(1)


def test_reproducible_and_seed_dependent():
    a = SyntheticDemonstrator(5).subject(1).experiment(0).recording
    b = SyntheticDemonstrator(5).subject(1).experiment(0).recording
    c = SyntheticDemonstrator(6).subject(1).experiment(0).recording
    np.testing.assert_array_equal(a.positions, b.positions)
    assert a.n_frames != c.n_frames or not np.array_equal(a.positions, c.positions, equal_nan=True)


def test_segments_cycle_and_sit_on_speed_minima(experiment):
    rec, segs, truth = experiment
    labels = [s.label for s in segs]
    assert labels == ["idle"] + ["strike_out", "throw", "swing_out", "idle"] * 8
    assert segs[0].start_frame == rec.frames[0] and segs[-1].end_frame == rec.frames[-1]
    for s0, s1 in zip(segs, segs[1:]):
        assert s0.end_frame == s1.start_frame and s0.start_frame < s0.end_frame
    # The "manual" borders are the exact ones give or take an annotator's jitter.
    manual = np.array([s.start_frame for s in segs])
    assert 0 < np.abs(manual - truth.segment_starts).max() <= 0.1 * rec.frequency
    assert truth.segment_labels == labels
    exact = [Segment(int(a), int(b), lab) for a, b, lab in zip(truth.segment_starts, truth.segment_ends, truth.segment_labels)]
    speed = truth.hand_speed
    for s0, s1 in zip(exact, exact[1:]):
        if (s0.label, s1.label) in (("strike_out", "throw"), ("throw", "swing_out")):
            i = rec.frame_index(s0.end_frame)
            # A local minimum of hand speed, well below the neighbouring peaks.
            assert speed[i] <= speed[i - 3 : i + 4].min() + 1e-9
            peaks = min(speed[rec.frame_index(s0.start_frame) : i].max(), speed[i : rec.frame_index(s1.end_frame)].max())
            assert speed[i] < 0.6 * peaks  # sub-movements overlap only a little


def test_throw_kinematics_are_plausible(experiment):
    rec, segs, truth = experiment
    for s in segs:
        if s.label != "throw":
            continue
        a, b = rec.frame_index(s.start_frame), rec.frame_index(s.end_frame)
        peak = truth.hand_speed[a:b].max()
        assert 2.0 < peak < 8.0  # a few m/s
        assert np.all(truth.hand_position[a:b, 2] > truth.shoulder[a:b, 2])  # overhand
    idle = [s for s in segs if s.label == "idle"]
    for s in idle[1:-1]:
        a, b = rec.frame_index(s.start_frame) + 20, rec.frame_index(s.end_frame) - 20
        if b > a:
            assert truth.hand_speed[a:b].max() < 0.3
    # Ball lands near the target, about 2 m away.
    dist = np.linalg.norm(truth.landing_points[:, :2] - truth.target[:2], axis=1)
    assert np.median(dist) < 0.4
    assert 1.4 < np.linalg.norm(truth.target[:2]) < 2.6


def test_ball_flies_ballistically_then_leaves(experiment):
    rec, _, truth = experiment
    ball = truth.clean_positions[:, MARKER_NAMES.index("Ball")]
    for r in rec.frames.searchsorted(truth.release_frames):
        flight = ball[r + 2 : r + 20]
        flight = flight[~np.isnan(flight).any(axis=1)]
        assert len(flight) > 10
        acc = np.diff(flight, 2, axis=0) * rec.frequency**2
        np.testing.assert_allclose(acc, np.tile([0, 0, -9.81], (len(acc), 1)), atol=1e-6)
        assert np.isnan(ball[r + 60]).all()  # out of the capture volume


def test_noise_gaps_and_rigid_plates(experiment):
    rec, _, truth = experiment
    err = rec.positions - truth.clean_positions
    rms_mm = np.sqrt(np.nanmean(np.sum(err**2, axis=2))) * 1000
    assert 0.4 < rms_mm < 1.5
    body = rec.positions[:, :8]
    missing = np.isnan(body).any(axis=2).mean()
    assert 0.001 < missing < 0.1
    for plate in (am.BACK_PLATE, am.HAND_PLATE):
        names = list(plate)
        d = np.linalg.norm(rec.marker(names[0]) - rec.marker(names[1]), axis=1)
        assert np.nanstd(d) < 0.002
        np.testing.assert_allclose(np.nanmedian(d), np.linalg.norm(plate[names[0]] - plate[names[1]]), atol=5e-4)


def test_truth_hand_pose_matches_the_markers(experiment):
    _, _, truth = experiment
    idx = [MARKER_NAMES.index(n) for n in am.HAND_PLATE]
    pos, quat = am.fit_plate_pose(truth.clean_positions[:, idx], am.HAND_PLATE)
    np.testing.assert_allclose(pos, truth.hand_position, atol=1e-9)
    dots = np.abs(np.sum(quat * truth.hand_quaternion, axis=1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(truth.hand_quaternion, axis=1), 1.0, atol=1e-12)


@pytest.mark.parametrize("shuffle", ["gap", "frame"])
def test_unlabeled_variant_keeps_every_sample(experiment, shuffle):
    rec = experiment.recording
    un, label = make_unlabeled(rec, np.random.default_rng(0), ghost_rate=0.5, shuffle=shuffle)
    assert all(n.startswith("Unnamed") for n in un.marker_names)
    assert (label == -1).any()  # ghosts
    for col in range(rec.n_markers):
        f, slot = np.nonzero(label == col)
        np.testing.assert_array_equal(un.positions[f, slot], rec.positions[f, col])
        assert len(f) == rec.visible()[:, col].sum()
    assert np.isnan(un.positions[label == -2]).all()


def test_dataset_files_and_cli(tmp_path):
    summary = generate_dataset(tmp_path / "d", n_subjects=1, n_experiments=2, n_throws=2, seed=1)
    assert summary.files == ["subject1_run1.tsv", "subject1_run2.tsv"]
    path = tmp_path / "d" / "subject1_run1.tsv"
    rec = read_tsv(path)
    assert rec.marker_names == MARKER_NAMES and rec.frequency == 100.0
    segs = read_segmentation(segmentation_path(path))
    assert [s.label for s in segs].count("throw") == 2
    truth = ExperimentTruth.load(tmp_path / "d" / "subject1_run1_truth.npz")
    assert truth.segment_labels == [s.label for s in segs]
    np.testing.assert_allclose(truth.hand_position[0], SyntheticDemonstrator(1, 2).subject(0).experiment(0).truth.hand_position[0], atol=1e-6)
    un = read_tsv(tmp_path / "d" / "unlabeled" / "subject1_run1.tsv")
    assert un.n_frames == rec.n_frames
    assert main(["mocap", "synthesize", "--out", str(tmp_path / "c"), "--subjects", "1", "--experiments", "1", "--throws", "1", "--json"]) == 0
    assert json.loads((tmp_path / "c" / "dataset.json").read_text())["n_throws"] == 1
    assert main(["mocap", "synthesize", "--out", str(tmp_path / "e"), "--subjects", "0"]) == 2


def test_bad_parameters():
    with pytest.raises(ValueError, match="n_throws"):
        SyntheticDemonstrator(0, n_throws=0)
    with pytest.raises(ValueError, match="shuffle"):
        make_unlabeled(SyntheticDemonstrator(0, 1).subject(0).experiment(0).recording, np.random.default_rng(0), shuffle="x")


@pytest.mark.slow
def test_full_default_dataset_is_quick(tmp_path):
    import time

    t0 = time.perf_counter()
    summary = generate_dataset(tmp_path / "full")
    elapsed = time.perf_counter() - t0
    assert len(summary.files) == 30
    assert elapsed < 60.0  # seconds, not minutes (shared CPU)
    throws = sum(
        [s.label for s in read_segmentation(segmentation_path(tmp_path / "full" / f))].count("throw") for f in summary.files
    )
    assert throws == 240


def test_labelled_files_have_only_short_gaps_long_ones_go_to_the_unlabelled_variant():
    from besdrake.mocap.gaps import find_gaps

    demo = SyntheticDemonstrator(0)
    n_long = 0
    for i in range(4):
        subj = demo.subject(i)
        exp = subj.experiment(0)
        rec = exp.recording
        body = rec.visible()[:, :8]
        for _col, a, b in find_gaps(body):
            assert b - a <= 0.2 * rec.frequency  # fillable by downstream preprocessing
            assert a >= 0.1 * rec.frequency and b <= rec.n_frames - 0.1 * rec.frequency
        n_long += int(exp.truth.long_occlusions.any())
        un, label = subj.unlabeled_experiment(0, exp)
        for col in range(8):
            hidden = exp.truth.long_occlusions[:, col]
            assert not (label[hidden] == col).any()
    assert n_long >= 1
