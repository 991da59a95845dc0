"""Annotation conventions: pauses, border speed levels and distance from speed minima."""

from __future__ import annotations

import numpy as np
import pytest

from besdrake.mocap.segments_io import Segment
from besdrake.segmentation.conventions import annotation_conventions, border_contexts, pauses
from besdrake.segmentation.evaluation import labelled_recordings

FREQ = 60.0


def bell(t, centre, width, height=1.0):
    return height * np.exp(-0.5 * ((t - centre) / width) ** 2)


def level_crossing(speed, peak_index, level, forward):
    """First frame from the peak on where the speed is below ``level`` of the peak."""
    step = 1 if forward else -1
    k = peak_index
    while speed[k] >= level * speed[peak_index]:
        k += step
    return k


def test_pause_edges_at_a_tenth_of_the_peak_are_measured_as_such():
    t = np.arange(400.0)
    speed = bell(t, 80, 15) + bell(t, 300, 15)  # movement, 2 s apart, movement
    end = level_crossing(speed, 80, 0.1, forward=True)
    start = level_crossing(speed, 300, 0.1, forward=False)
    segs = [Segment(0, end, "a"), Segment(start, 399, "b")]
    assert pauses(segs, FREQ) == [(end, start)]
    ctx = border_contexts(segs, speed, FREQ, first_frame=0)
    assert [c.frame for c in ctx] == [end, start]
    assert all(c.pause_edge for c in ctx)
    for c in ctx:
        assert 0.08 <= c.speed_fraction <= 0.1
        assert abs(c.from_minimum_s) > 0.3  # the speed minimum is mid-pause, far from either edge


def test_back_to_back_segments_cut_at_the_minimum_are_not_pauses():
    t = np.arange(300.0)
    speed = bell(t, 75, 15) + bell(t, 225, 15) + 0.001
    m = int(np.argmin(speed[50:250])) + 50
    segs = [Segment(100, m + 100, "a"), Segment(m + 100, 399, "b")]  # the file numbers frames from 100
    assert pauses(segs, FREQ) == []
    (c,) = border_contexts(segs, speed, FREQ, first_frame=100)
    assert c.frame == m + 100 and not c.pause_edge
    assert c.from_minimum_s == 0.0 and c.speed_fraction < 0.01


def test_bad_input_is_a_clear_error():
    segs = [Segment(0, 10, "a"), Segment(10, 20, "b")]
    with pytest.raises(ValueError, match="finite"):
        border_contexts(segs, np.array([0.1, np.nan, 0.2, 0.3]), FREQ, 0)
    with pytest.raises(ValueError, match="at least one"):
        annotation_conventions([])


def test_the_two_pick_and_place_annotators_differ_in_pauses_and_levels(shared_data):
    recs = labelled_recordings(shared_data / "pick_and_place")
    conv = {s: annotation_conventions([r for r in recs if r.path.name.startswith(s + "_")])
            for s in ("subject1", "subject2")}
    one, two = conv["subject1"], conv["subject2"]
    # subject 1's annotator leaves a pause between most movements, subject 2's rarely
    assert one.pause_edge_share > 0.4 > 0.2 > two.pause_edge_share
    # both place pause edges at roughly a tenth of the peak speed ...
    for c in (one, two):
        assert 0.05 < c.pause_edge_speed_fraction_quartiles[1] < 0.15
    # ... but only subject 2's cuts back-to-back movements at the speed minimum
    assert two.other_speed_fraction_quartiles[1] < 0.04 < one.other_speed_fraction_quartiles[1]
    assert two.near_minimum_share > 0.7 > 0.5 > one.near_minimum_share


def test_cli_eval_segmentation_prints_both_folders_conventions(shared_data, tmp_path, capsys):
    import json

    from besdrake.cli import main

    for subject, run in (("one", "subject1_run1"), ("two", "subject2_run1")):
        (tmp_path / subject).mkdir()
        for suffix in (".tsv", "_manually_segmented.json"):
            (tmp_path / subject / (run + suffix)).symlink_to(shared_data / "pick_and_place" / (run + suffix))
    args = ["eval", "segmentation", "--data", str(tmp_path / "one"), "--tune-on", str(tmp_path / "two"),
            "--no-baseline", "--conventions"]
    assert main(args + ["--json"]) == 0
    conv = json.loads(capsys.readouterr().out)["annotation_conventions"]
    assert set(conv) == {"data", "tune_on"}
    assert conv["data"]["n_pauses"] > conv["tune_on"]["n_pauses"] == 0  # subject 2's run 1 has none
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "conventions of data:" in text and "conventions of tune_on:" in text


def test_bench_within_subject_pools_the_left_out_recordings(shared_data, script, monkeypatch):
    """--within-subject: each recording scored by rules tuned on the others; counts pooled, not F1s averaged."""
    from besdrake.mocap.preprocess import preprocess
    from besdrake.segmentation import tune_vmci
    from besdrake.segmentation.evaluation import evaluate_segmenter

    bench = script("bench_segmentation")
    monkeypatch.setattr(bench, "VMCI_GRID", {"noise_ratio": [0.3]})
    recs = [r for r in labelled_recordings(shared_data / "pick_and_place")
            if r.path.name in ("subject1_run1.tsv", "subject1_run4.tsv")]
    pre = {str(r.path): preprocess(r.recording) for r in recs}
    out = bench.within_subject({"subject1": recs}, pre)["subject1"]
    scores = [evaluate_segmenter(tune_vmci([other], {"noise_ratio": [0.3]}, preprocessed=pre).segmenter(),
                                 [left_out], (0.1, 0.2), pre).scores["starts_and_ends"]
              for left_out, other in ((recs[0], recs[1]), (recs[1], recs[0]))]
    assert out["n_true"] == sum(s[0.1].n_true for s in scores)
    for t in (0.1, 0.2):
        matched = sum(s[t].n_matched for s in scores)
        assert out[f"f1_{t}"] == round(2 * matched / sum(s[t].n_true + s[t].n_pred for s in scores), 4)
