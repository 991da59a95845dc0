"""Automatic marker labelling and gap filling."""

from __future__ import annotations

import json

import numpy as np
import pytest

from besdrake.cli import main
from besdrake.mocap.gaps import fill_gaps, find_gaps
from besdrake.mocap.labeling import EMPTY, GHOST, LabelingError, MarkerLabeler, labeling_accuracy
from besdrake.mocap.qualisys import read_tsv, write_tsv
from besdrake.mocap.recording import MocapRecording
from besdrake.tasks.throwing.demonstrator import SyntheticDemonstrator, make_unlabeled


@pytest.fixture(scope="module")
def subject():
    return SyntheticDemonstrator(seed=0).subject(1)


@pytest.fixture(scope="module")
def labeler(subject):
    return MarkerLabeler().fit(subject.experiment(0).recording)


@pytest.fixture(scope="module")
def experiment(subject):
    return subject.experiment(1)


def test_learns_the_plates(labeler):
    names = labeler.marker_names_
    plates = sorted(sorted(names[i] for i in p) for p in labeler.plates_)
    assert plates == [["Back left", "Back right", "Back top"], ["Hand left", "Hand right", "Hand top"]]


@pytest.mark.parametrize("shuffle", ["gap", "frame"])
def test_labels_unnamed_trajectories(labeler, subject, experiment, shuffle):
    un, truth = make_unlabeled(experiment.recording, np.random.default_rng(11), subject.style.ghost_rate * 2, shuffle)
    assert (truth == GHOST).sum() > 50
    res = labeler.predict(un)
    acc = labeling_accuracy(res.slot_labels, truth)
    assert acc["correct_share"] > 0.99
    assert acc["marker_correct_share"] > 0.99
    assert acc["ghost_rejected_share"] > 0.5
    assert res.recording.marker_names == experiment.recording.marker_names
    # Before gap filling, every labelled sample is the original one.
    raw = res.raw_recording.positions
    both = ~np.isnan(raw).any(axis=2) & experiment.recording.visible()
    assert both.sum() > 0.98 * experiment.recording.visible().sum()
    np.testing.assert_allclose(raw[both], experiment.recording.positions[both])


def test_filled_gaps_are_close_to_the_truth(labeler, subject, experiment):
    un, _ = make_unlabeled(experiment.recording, np.random.default_rng(3), 0.0)
    res = labeler.predict(un)
    rec = res.recording
    filled = np.isnan(res.raw_recording.positions).any(axis=2) & ~np.isnan(rec.positions).any(axis=2)
    assert filled.sum() > 20
    err = np.linalg.norm(rec.positions - experiment.truth.clean_positions, axis=2)
    assert np.median(err[filled]) < 0.005
    assert np.percentile(err[filled], 95) < 0.03
    methods = {g.method for g in res.gaps}
    assert "rigid" in methods and "spline" in methods
    assert any(g.reason == "too long" for g in res.gaps)  # the ball between throws


def test_gap_filling_exact_cases():
    t = np.arange(50) / 100.0
    n = len(t)
    # A marker moving on a parabola (spline is exact) and a plate spinning about an axis
    # through two of its markers (rigid fill is exact).
    line = np.stack([t, 2 * t, 1 - 4.9 * t**2], axis=1)
    angle = 3.0 * t
    a = np.zeros((n, 3))
    b = np.tile([0.05, 0.0, 0.0], (n, 1))
    c = np.stack([0.02 * np.ones(n), 0.03 * np.cos(angle), 0.03 * np.sin(angle)], axis=1) + [0, 0, 1.0]
    a += [0, 0, 1.0]
    b += [0, 0, 1.0]
    pos = np.stack([line, a, b, c], axis=1)
    rec = MocapRecording(["m", "a", "b", "c"], pos.copy(), 100.0)
    rec.positions[20:26, 0] = np.nan
    rec.positions[20:30, 3] = np.nan
    rec.positions[0:3, 1] = np.nan  # at the edge: not filled
    res = fill_gaps(rec, max_gap_s=0.25, plates=[["a", "b", "c"]])
    np.testing.assert_allclose(res.recording.positions[20:26, 0], pos[20:26, 0], atol=1e-9)
    np.testing.assert_allclose(res.recording.positions[20:30, 3], pos[20:30, 3], atol=1e-9)
    by_marker = {g.marker: g for g in res.gaps}
    assert by_marker["m"].method == "spline" and by_marker["c"].method == "rigid"
    assert by_marker["a"].method == "none" and by_marker["a"].reason == "at edge"
    assert np.isnan(res.recording.positions[0:3, 1]).all()
    # Too long.
    rec2 = MocapRecording(["m"], line[:, None, :].copy(), 100.0)
    rec2.positions[5:40, 0] = np.nan
    res2 = fill_gaps(rec2, max_gap_s=0.1)
    assert res2.gaps[0].reason == "too long" and not res2.gaps[0].filled
    assert res2.gaps[0].start_frame == 6 and res2.gaps[0].end_frame == 40  # 1-based frames
    assert find_gaps(np.array([[True], [False], [False], [True]])) == [(0, 1, 3)]
    with pytest.raises(ValueError, match="max_gap_s"):
        fill_gaps(rec2, max_gap_s=-1)


def test_marker_never_visible_is_flagged(labeler, experiment):
    rec = experiment.recording.copy()
    rec.positions[:, rec.marker_index("Elbow")] = np.nan
    un, _ = make_unlabeled(rec, np.random.default_rng(0), 0.0)
    res = labeler.predict(un)
    assert res.never_seen == ["Elbow"]
    assert any("never found" in w for w in res.warnings)
    assert any(g.marker == "Elbow" and g.reason == "never visible" for g in res.gaps)
    assert res.summary()["never_seen"] == ["Elbow"]


def test_bad_input(experiment):
    with pytest.raises(LabelingError, match="not fitted"):
        MarkerLabeler().predict(experiment.recording)
    ref = experiment.recording.copy()
    ref.positions[:, ref.marker_index("Shoulder")] = np.nan
    with pytest.raises(LabelingError, match="never visible.*Shoulder"):
        MarkerLabeler().fit(ref)
    short = experiment.recording.crop(1, 1)
    with pytest.raises(LabelingError, match="too short"):
        MarkerLabeler().fit(short)
    lab = MarkerLabeler().fit(experiment.recording)
    with pytest.raises(LabelingError, match="too short"):
        lab.predict(short)


def test_accuracy_measure():
    truth = np.array([[0, 1, GHOST, EMPTY], [1, 0, EMPTY, EMPTY]])
    pred = np.array([[0, 1, 2, EMPTY], [0, 1, EMPTY, EMPTY]])
    acc = labeling_accuracy(pred, truth)
    assert acc["samples"] == 5 and acc["correct_share"] == pytest.approx(2 / 5)
    assert acc["ghost_rejected_share"] == 0.0
    with pytest.raises(ValueError, match="shapes"):
        labeling_accuracy(pred[:1], truth)


def test_cli(tmp_path, subject, experiment):
    ref_path, un_path, out = tmp_path / "ref.tsv", tmp_path / "un.tsv", tmp_path / "out.tsv"
    write_tsv(subject.experiment(0).recording, ref_path)
    un, _ = subject.unlabeled_experiment(1, experiment)
    write_tsv(un, un_path)
    assert main(["mocap", "label", str(un_path), "--reference", str(ref_path), "--out", str(out), "--json"]) == 0
    labelled = read_tsv(out)
    assert labelled.marker_names == experiment.recording.marker_names
    vis = experiment.recording.visible()
    err = np.linalg.norm(labelled.positions - experiment.recording.positions, axis=2)[vis]
    assert np.mean(err < 0.001) > 0.99
    bad = tmp_path / "bad.tsv"
    bad.write_text("NO_OF_FRAMES\t2\nFREQUENCY\t100\n")
    assert main(["mocap", "label", str(un_path), "--reference", str(bad), "--out", str(out)]) == 2
    assert main(["mocap", "label", str(un_path), "--reference", str(ref_path), "--out", str(tmp_path / "x.csv")]) == 2


def test_summary_is_json_serialisable(labeler, experiment):
    un, _ = make_unlabeled(experiment.recording, np.random.default_rng(1), 0.2)
    res = labeler.predict(un)
    s = json.loads(json.dumps(res.summary()))
    assert s["frames"] == experiment.recording.n_frames
    assert s["gaps_flagged"] == len(s["flagged_gaps"])


@pytest.mark.slow
def test_all_subjects_above_99_percent():
    """The benchmark's figure as a check: every subject, reference = experiment 1."""
    demo = SyntheticDemonstrator(seed=0)
    correct = total = 0
    for i in range(10):
        subj = demo.subject(i)
        lab = MarkerLabeler().fit(subj.experiment(0).recording)
        for j in (1, 2):
            un, truth = subj.unlabeled_experiment(j)
            acc = labeling_accuracy(lab.predict(un).slot_labels, truth)
            correct += acc["correct_share"] * acc["samples"]
            total += acc["samples"]
            assert acc["correct_share"] > 0.98
    assert correct / total > 0.99


def test_marker_set_without_plates_uses_the_initial_pose(subject, experiment):
    names = ["Back top", "Shoulder", "Elbow", "Hand top", "Ball"]
    lab = MarkerLabeler().fit(subject.experiment(0).recording.select(names))
    assert lab.plates_ == []
    un, truth = make_unlabeled(experiment.recording.select(names), np.random.default_rng(0), 0.2)
    acc = labeling_accuracy(lab.predict(un).slot_labels, truth, names)
    assert acc["correct_share"] > 0.99
    assert min(acc["per_marker"].values()) > 0.98


def test_rejects_bad_parameters():
    with pytest.raises(ValueError, match="track_gate"):
        MarkerLabeler(track_gate=0.0)
