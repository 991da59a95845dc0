"""1-NN movement classification of segments."""

from __future__ import annotations

import json

import numpy as np
import pytest

from besdrake.cli import main
from besdrake.segmentation.classification import (
    ClassificationError,
    MovementSegment,
    SegmentClassifier,
    SegmentFeatures,
    normalise_label,
)

NAMES = ["Hand top", "Hand right", "Hand left", "Elbow"]


def make_segment(start, end, duration, freq=100.0, bend=0.0, rng=None, noise=0.003, label=None):
    """A min-jerk hand path from start to end (curved by ``bend``) with an elbow following it."""
    n = int(round(duration * freq))
    tau = np.linspace(0, 1, n)
    s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
    hand = start[None] + s[:, None] * (end - start)[None]
    hand[:, 2] += bend * np.sin(np.pi * s)
    offs = np.array([[0, 0, 0.02], [0, -0.02, 0], [0, 0.02, 0]])
    pos = np.stack([hand + o for o in offs] + [0.5 * hand + np.array([0, -0.2, 0])], axis=1)
    if rng is not None:
        pos = pos + rng.normal(0, noise, pos.shape)
    return MovementSegment(NAMES, pos, freq, 0, n - 1, label)


def toy_dataset(seed, n_per_class=6):
    """Three classes: reach forward, reach up (curved), retract; random durations and offsets."""
    rng = np.random.default_rng(seed)
    segs, labels = [], []
    for _ in range(n_per_class):
        jitter = rng.normal(0, 0.03, 3)
        d = rng.uniform(0.6, 1.4)
        segs.append(make_segment(np.array([0.2, -0.2, 0.0]) + jitter, np.array([0.6, -0.2, 0.1]) + jitter, d, rng=rng))
        labels.append("reach_forward")
        segs.append(make_segment(np.array([0.2, -0.2, 0.0]) + jitter, np.array([0.4, -0.2, 0.5]) + jitter, d, rng=rng, bend=0.1))
        labels.append("reach_up")
        segs.append(make_segment(np.array([0.6, -0.2, 0.1]) + jitter, np.array([0.2, -0.2, 0.0]) + jitter, d, rng=rng))
        labels.append("retract")
    return segs, labels


def test_toy_classes_are_separated():
    Xtr, ytr = toy_dataset(0)
    Xte, yte = toy_dataset(1)
    clf = SegmentClassifier(markers=("hand",)).fit(Xtr, ytr)
    assert clf.score(Xte, yte) == 1.0
    assert set(clf.classes_) == {"reach_forward", "reach_up", "retract"}


def test_time_normalisation_makes_speed_irrelevant():
    a = make_segment(np.zeros(3), np.array([0.5, 0, 0]), 0.5)
    b = make_segment(np.zeros(3), np.array([0.5, 0, 0]), 1.7)
    f = SegmentFeatures(markers=("hand",), velocity_weight=0.3)
    assert np.allclose(f.transform_one(a), f.transform_one(b), atol=2e-3)
    # but the duration feature (off by default) tells them apart
    g = SegmentFeatures(markers=("hand",), duration_weight=1.0)
    assert abs(g.transform_one(a)[-1] - g.transform_one(b)[-1]) == pytest.approx(1.2, abs=0.02)


def test_part_labels_map_to_parent():
    assert normalise_label("approach_right_part") == "approach_right"
    assert normalise_label("approach_right_part", "own") == "approach_right_part"
    assert normalise_label("idle") == "idle"
    segs, labels = toy_dataset(2)
    labels = [l + "_part" if i % 2 else l for i, l in enumerate(labels)]
    clf = SegmentClassifier(markers=("hand",)).fit(segs, labels)
    assert set(clf.classes_) == {"reach_forward", "reach_up", "retract"}


def test_json_round_trip_predicts_the_same():
    Xtr, ytr = toy_dataset(3)
    Xte, _ = toy_dataset(4)
    clf = SegmentClassifier(markers=("hand", "Elbow")).fit(Xtr, ytr)
    data = json.loads(json.dumps(clf.to_json()))
    clone = SegmentClassifier.from_json(data)
    assert list(clone.predict(Xte)) == list(clf.predict(Xte))
    with pytest.raises(ClassificationError, match="format"):
        SegmentClassifier.from_json({"format": "pickle"})


def test_auto_markers_skip_objects_with_gaps():
    segs, labels = toy_dataset(5)
    assert SegmentClassifier().fit(segs, labels).markers_ == ("hand", "Elbow")


def test_bad_input_is_a_clear_error():
    segs, labels = toy_dataset(6)
    with pytest.raises(ClassificationError, match="not fitted"):
        SegmentClassifier().predict(segs)
    with pytest.raises(ClassificationError, match="labels"):
        SegmentClassifier().fit(segs, labels[:-1])
    with pytest.raises(ClassificationError, match="no training segments"):
        SegmentClassifier().fit([], [])
    bad = make_segment(np.zeros(3), np.ones(3), 0.5)
    bad.positions_back[10, 0] = np.nan
    clf = SegmentClassifier(markers=("hand",)).fit(segs, labels)
    with pytest.raises(ClassificationError, match="missing samples"):
        clf.predict([bad])
    short = MovementSegment(NAMES, np.zeros((2, 4, 3)), 100.0)
    with pytest.raises(ClassificationError, match="at least 3"):
        clf.predict([short])
    with pytest.raises(ClassificationError, match="no marker"):
        SegmentClassifier(markers=("Ball",)).fit(segs, labels)


def _subject_dirs(shared_data, tmp_path):
    dirs = {}
    for subject in ("subject1", "subject2"):
        d = tmp_path / subject
        d.mkdir()
        for f in (shared_data / "pick_and_place").glob(subject + "_*"):
            (d / f.name).symlink_to(f)
        dirs[subject] = d
    return dirs


def test_real_cross_subject_accuracy(shared_data, tmp_path):
    """Measured: 97.4% trained on subject 1, 96.8% trained on subject 2."""
    from besdrake.segmentation.evaluation import evaluate_classifier, labelled_recordings

    dirs = _subject_dirs(shared_data, tmp_path)
    s1, s2 = labelled_recordings(dirs["subject1"]), labelled_recordings(dirs["subject2"])
    r12 = evaluate_classifier(SegmentClassifier(), s1, s2)
    r21 = evaluate_classifier(SegmentClassifier(), s2, s1)
    assert r12["accuracy"] >= 0.95
    assert r21["accuracy"] >= 0.95
    movement = [c for c in r21["per_class_accuracy"] if c != "idle"]
    assert all(r21["per_class_accuracy"][c] >= 0.95 for c in movement)
    # the hand path alone (the quoted baseline's features) does worse the hard way round
    base = evaluate_classifier(
        SegmentClassifier(markers=("hand",), velocity_weight=0.0, path_length_weight=0.0), s2, s1
    )
    assert base["accuracy"] < r21["accuracy"]


def test_cli_eval_classification_and_segment_labels(shared_data, tmp_path, capsys):
    dirs = _subject_dirs(shared_data, tmp_path)
    model = tmp_path / "clf.json"
    assert main(["eval", "classification", "--train", str(dirs["subject1"]), "--test", str(dirs["subject2"]),
                 "--json", "--save-classifier", str(model)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["k"] == 1 and out["n_test"] == 38
    assert set(out["per_class_accuracy"]) >= {"approach_forward", "move_obj_shelf", "idle"}
    assert "part" in out["part_policy"]
    rec = shared_data / "pick_and_place" / "subject2_run1.tsv"
    assert main(["segment", str(rec), "--json", "--classifier", str(model)]) == 0
    segs = json.loads(capsys.readouterr().out)["segments"]
    labels = [s["label"] for s in segs]
    # the manual sequence of this run (its slow first approach is labelled idle at present)
    for expected in ("move_obj_table", "move_to_rest_right", "approach_right", "move_obj_shelf", "move_to_rest_down"):
        assert expected in labels
    assert labels.index("move_obj_table") < labels.index("approach_right") < labels.index("move_obj_shelf")


@pytest.mark.slow
def test_synthetic_throws_new_subjects(tmp_path):
    """Train on synthetic subjects 1-5, test on 6-10 (measured: 100%, every throw found)."""
    from besdrake.mocap.preprocess import preprocess
    from besdrake.tasks.throwing.demonstrator import generate_dataset
    from besdrake.segmentation import VMCI, extract_segment
    from besdrake.segmentation.evaluation import evaluate_classifier, labelled_recordings

    generate_dataset(tmp_path, n_subjects=10, n_experiments=1, n_throws=6, seed=3, unlabeled=False)
    recs = labelled_recordings(tmp_path)
    number = lambda r: int(r.path.name.split("_")[0][len("subject"):])  # noqa: E731
    train = [r for r in recs if number(r) <= 5]
    test = [r for r in recs if number(r) > 5]
    clf = SegmentClassifier()
    res = evaluate_classifier(clf, train, test)
    assert res["accuracy"] >= 0.95
    assert res["per_class_accuracy"]["throw"] >= 0.99
    for rec in test:
        pre = preprocess(rec.recording)
        seg = VMCI().fit(pre)
        starts = pre.frames[[a for a, _ in seg.segments_]]
        ends = pre.frames[[b for _, b in seg.segments_]]
        for s in rec.segments:
            if s.label == "throw":
                tol = 0.2 * pre.frequency
                hit = np.flatnonzero((np.abs(starts - s.start_frame) <= tol) & (np.abs(ends - s.end_frame) <= tol))
                assert len(hit) == 1, f"{rec.path.name}: throw {s} not found"
                a, b = seg.segments_[hit[0]]
                assert clf.predict([extract_segment(pre, a, b)])[0] == "throw"
