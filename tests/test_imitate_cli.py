"""``besdrake imitate``: demonstrations -> motion plans, and its handling of bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from besdrake.cli import main


def test_imitate_writes_a_plan_per_throw_and_a_summary(tmp_path, capsys):
    rc = main(["imitate", "synthetic:0:0", "--segments", "given", "--max-throws", "2", "--out", str(tmp_path), "--json", "--no-figures"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["n_throws"] == 2 and summary["n_executable"] == 2
    throw = summary["recordings"][0]["throws"][0]
    assert throw["simulation"]["flags"] is not None  # simulated in the nominal scenario
    plan = json.loads((tmp_path / "synthetic_s0_e0_throw0.plan.json").read_text())
    assert np.asarray(plan["q"]).shape[1] == 6
    assert (tmp_path / "summary.json").is_file()


def test_imitate_reports_a_missing_file_clearly(tmp_path, capsys):
    assert main(["imitate", str(tmp_path / "nope.tsv"), "--out", str(tmp_path)]) == 2
    assert "no such recording" in capsys.readouterr().err


def test_a_throw_with_nan_samples_is_reported_and_the_others_still_imitated(tmp_path):
    from besdrake.tasks.throwing.imitation import imitate_recording, load_demonstration, prepare

    name, rec, segments = load_demonstration("synthetic:0:0")[0]
    pre = prepare(rec)
    throws = [(s.start_frame, s.end_frame) for s in segments if s.label == "throw"][:2]
    bad = np.flatnonzero((pre.frames >= throws[0][0]) & (pre.frames <= throws[0][1]))[5]
    pre.hand_position_back[bad] = np.nan
    reports = imitate_recording(name, pre, throws, simulate=False)
    assert not reports[0].ok and "NaN" in reports[0].error
    assert reports[1].ok and reports[1].error is None


def test_too_short_segment_is_a_clear_error():
    from besdrake.embodiment import RecordMappingError, hand_trajectory
    from besdrake.tasks.throwing.imitation import load_demonstration, prepare

    _, rec, _ = load_demonstration("synthetic:0:0")[0]
    pre = prepare(rec)
    f0 = int(pre.frames[100])
    with pytest.raises(RecordMappingError, match="at least"):
        hand_trajectory(pre, f0, f0 + 2)
