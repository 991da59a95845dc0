"""Imitation of many throws on worker processes: the same reports and files as one after the other."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from besdrake.tasks.throwing.imitation import load_demonstration, prepare
from besdrake.tasks.throwing.imitation_pool import ThrowJob, imitate_throws


def _jobs() -> list[ThrowJob]:
    """A throw of the synthetic demonstrator, and the same throw with a NaN sample (it cannot be imitated)."""
    name, rec, segments = load_demonstration("synthetic:0:0")[0]
    pre = prepare(rec)
    f0, f1 = next((s.start_frame, s.end_frame) for s in segments if s.label == "throw")
    bad = replace(pre, hand_position_back=pre.hand_position_back.copy())
    bad.hand_position_back[np.flatnonzero((pre.frames >= f0) & (pre.frames <= f1))[5]] = np.nan
    return [ThrowJob(f"{name}_throw0", 0, pre, f0, f1, figure=False), ThrowJob(f"{name}_bad", 1, bad, f0, f1, figure=False)]


def test_two_workers_give_the_reports_and_files_of_one_after_the_other(tmp_path):
    jobs = _jobs()
    (tmp_path / "one").mkdir()
    (tmp_path / "two").mkdir()
    serial = imitate_throws(jobs, "nominal", out_dir=tmp_path / "one", workers=1)
    pooled = imitate_throws(jobs, "nominal", out_dir=tmp_path / "two", workers=2)
    assert [r.ok for r in pooled] == [True, False] and "NaN" in pooled[1].error  # a bad throw is reported
    for a, b in zip(serial, pooled):
        assert (a.index, a.ok, a.error) == (b.index, b.ok, b.error)
        assert a.summary.get("execution_time_s") == b.summary.get("execution_time_s")
        assert (a.landing or {}).get("touchdown_m") == (b.landing or {}).get("touchdown_m")
    names = sorted(p.name for p in (tmp_path / "one").iterdir())
    assert names == sorted(p.name for p in (tmp_path / "two").iterdir()) and len(names) >= 2
    for n in names:
        if n.endswith(".dmp.json"):
            assert (tmp_path / "one" / n).read_bytes() == (tmp_path / "two" / n).read_bytes()
