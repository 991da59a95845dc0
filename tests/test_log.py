"""The measured-data log: round trip of every field, resume after a kill, corrupt folders, no hidden truth."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from besdrake.plan import MotionPlan
from besdrake.tasks.throwing.throws import default_throw
from besdrake.transfer.lab import SafetyGate
from besdrake.transfer.log import LabLog, LogError, read_log, run_plans
from besdrake.tasks.throwing.measurement import ThrowMeasurement
from besdrake.transfer.measurement import Measurement, MeasurementError
from besdrake.tasks.throwing.lab import VirtualLab, parse_lab_config

# Distinctive hidden values, so that a leak cannot hide among ordinary numbers.
HIDDEN = {"base_offset": {"z": -0.0317}, "actuator_lag": {"delay": 0.0123, "tau": 0.0179}}


def noisy_config(effects=None, seed=11):
    return {
        "name": "log_test_lab",
        "description": "virtual lab for the log tests",
        "scenario": "nominal",
        "seed": seed,
        "effects": effects or {},
        "noise": {"touchdown_sd": 0.05, "ball_placement_sd": 0.002, "mocap_noise_sd": 0.001, "mocap_dropout": 0.05,
                  "encoder_noise_sd": 0.0005, "mocap_rate_hz": 200, "joint_rate_hz": 500},
    }


@pytest.fixture(scope="module")
def lab() -> VirtualLab:
    return VirtualLab(parse_lab_config(noisy_config(HIDDEN)))


def plans() -> list[MotionPlan]:
    out = [default_throw(a) for a in (0.25, 0.3, 0.35, 0.4, 0.45)]
    out.insert(2, default_throw(0.35, accel=30.0))  # refused by the gate
    return out


def assert_same(a: Measurement, b: Measurement, path_tol: float = 0.0) -> None:
    """Every field equal (the ball path up to the TSV's micrometre resolution)."""
    assert a.trial == b.trial
    np.testing.assert_array_equal(a.plan.t, b.plan.t)
    np.testing.assert_array_equal(a.plan.q, b.plan.q)
    if a.plan.qd is None:
        assert b.plan.qd is None
    else:
        np.testing.assert_array_equal(a.plan.qd, b.plan.qd)
    assert a.plan.meta == b.plan.meta
    for name in ("touchdown", "ball_t", "joint_t", "q_commanded", "q_measured"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            np.testing.assert_array_equal(x, y, err_msg=name)
    if a.ball_path is None:
        assert b.ball_path is None
    else:
        assert a.ball_path.shape == b.ball_path.shape
        np.testing.assert_array_equal(np.isnan(a.ball_path), np.isnan(b.ball_path))
        np.testing.assert_allclose(a.ball_path, b.ball_path, atol=path_tol, rtol=0)
    assert a.flags == b.flags and a.message == b.message and a.meta == b.meta


def test_log_round_trips_every_field(tmp_path, lab):
    gate = SafetyGate(lab)
    ms = [gate.execute(p) for p in plans()[:4]]
    assert ms[2].flags.get("refused_by_safety_gate")
    assert any(np.isnan(m.ball_path).any() for m in ms if m.ball_path is not None), "gaps must be exercised"
    odd = ThrowMeasurement(  # hand-made: a message with separators and newlines, empty ball path, extra flags, no qd
        trial=4,
        plan=MotionPlan(t=[0.0, 0.5, 1.0], q=np.zeros((3, 6)), meta={"name": "still"}),
        touchdown=None,
        ball_t=np.zeros(0),
        ball_path=np.zeros((0, 3)),
        flags={"ball_not_seen": True, "custom_flag": True, "aborted": False},
        message='line one, with "quotes";\nline two',
        meta={"operator": "besdrake test", "nested": {"a": [1, 2]}},
    )
    log = LabLog.create(tmp_path / "log", lab.description(), run={"seed": 11})
    for m in [*ms, odd]:
        log.append(m)
    back = read_log(tmp_path / "log")
    assert len(back) == 5 == len(LabLog.open(tmp_path / "log"))
    for a, b in zip([*ms, odd], back):
        assert_same(a, b, path_tol=6e-7)
    header = json.loads((tmp_path / "log" / "log.json").read_text())
    assert header["format"] == "besdrake-lab-log" and header["version"] == 1 and header["run"] == {"seed": 11}
    rows = (tmp_path / "log" / "trials.csv").read_text().splitlines()
    assert rows[0] == "trial,plan_hash,touchdown_x,touchdown_y,flags,message"
    assert rows[3].split(",")[4] == "refused_by_safety_gate"
    assert rows[5].split(",")[4] == "ball_not_seen;custom_flag"
    # ball.tsv is a Qualisys TSV in millimetres
    from besdrake.mocap.qualisys import read_tsv

    rec = read_tsv(tmp_path / "log" / "trials" / "000000" / "ball.tsv", check_units=False)
    assert rec.marker_names == ["ball"] and rec.frequency == 200.0
    text = (tmp_path / "log" / "trials" / "000000" / "ball.tsv").read_text()
    assert f"{ms[0].ball_path[0, 0] * 1000:.3f}" in text
    # the JSON form of a measurement round-trips too (NaN gaps as null)
    again = ThrowMeasurement.from_dict(json.loads(json.dumps(ms[0].to_dict())))
    assert_same(ms[0], again)


class KilledLab:
    """Wraps a lab and raises at trial ``kill_at`` (like a process killed mid-run)."""

    def __init__(self, lab, kill_at: int) -> None:
        self.lab, self.kill_at, self.name, self.robot = lab, kill_at, lab.name, lab.robot
        self.executed: list[int] = []

    def execute(self, plan, trial=None):
        if trial == self.kill_at:
            raise KeyboardInterrupt("killed")
        self.executed.append(trial)
        return self.lab.execute(plan, trial=trial)


def test_killed_run_resumes_without_repeats_or_losses(tmp_path, lab):
    ps = plans()
    ref = LabLog.create(tmp_path / "ref", lab.description())
    run_plans(SafetyGate(lab), ps, ref)
    log = LabLog.create(tmp_path / "run", lab.description())
    first = KilledLab(lab, kill_at=4)
    with pytest.raises(KeyboardInterrupt):
        run_plans(SafetyGate(first), ps, log)
    assert len(LabLog.open(tmp_path / "run")) == 4
    second = KilledLab(lab, kill_at=-1)
    summary = run_plans(SafetyGate(second), ps, LabLog.open(tmp_path / "run"))
    assert summary.skipped == 4 and summary.executed == 2 and summary.total == 6
    assert first.executed == [0, 1, 3] and second.executed == [4, 5], "trial 2 is refused by the gate; none is run twice"
    got, want = read_log(tmp_path / "run"), ref.measurements()
    assert [m.trial for m in got] == list(range(6))
    for a, b in zip(want, got):
        a.meta.pop("executed_at", None), b.meta.pop("executed_at", None)
        assert_same(a, b)


def test_interrupted_write_is_discarded_and_redone(tmp_path, lab, monkeypatch):
    ps = plans()[:4]
    log = LabLog.create(tmp_path / "run", lab.description())
    run_plans(SafetyGate(lab), ps[:2], log)

    def killed_before_row(m):
        raise KeyboardInterrupt("killed after the trial folder, before its row")

    monkeypatch.setattr(LabLog, "_row", staticmethod(killed_before_row))
    with pytest.raises(KeyboardInterrupt):
        run_plans(SafetyGate(lab), ps, log)
    monkeypatch.undo()
    assert (tmp_path / "run" / "trials" / "000002").is_dir(), "the folder was written..."
    reopened = LabLog.open(tmp_path / "run")
    assert len(reopened) == 2, "...but without its row the trial does not exist"
    # a row cut short by the kill (no newline) is dropped as well
    with open(tmp_path / "run" / "trials.csv", "a") as f:
        f.write("2,deadbeef,1.0")
    assert len(LabLog.open(tmp_path / "run")) == 2
    assert (tmp_path / "run" / "trials.csv").read_text().endswith("1.0"), "reading never modifies the log"
    run_plans(SafetyGate(lab), ps, LabLog.open(tmp_path / "run"))
    got = read_log(tmp_path / "run")
    assert [m.trial for m in got] == [0, 1, 2, 3]
    assert got[2].flags.get("refused_by_safety_gate")
    assert "deadbeef" not in (tmp_path / "run" / "trials.csv").read_text()


def test_resume_refuses_other_plans_and_append_checks_the_order(tmp_path, lab):
    ps = plans()[:2]
    log = LabLog.create(tmp_path / "run", lab.description())
    run_plans(SafetyGate(lab), ps, log)
    with pytest.raises(LogError, match="different plan"):
        run_plans(SafetyGate(lab), [ps[1], ps[0]], LabLog.open(tmp_path / "run"))
    with pytest.raises(LogError, match="holds 2 trials"):
        run_plans(SafetyGate(lab), ps[:1], LabLog.open(tmp_path / "run"))
    with pytest.raises(LogError, match="next is 2"):
        log.append(Measurement(trial=5, plan=ps[0]))
    import subprocess
    import sys

    # another process holding the writer's lock blocks appends (one writer per log)
    fresh = LabLog.create(tmp_path / "locked", lab.description())  # not yet written by this process
    holder = subprocess.Popen([sys.executable, "-c", (
        "import fcntl, sys, time; f = open(sys.argv[1], 'a+'); fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB); "
        "print('locked', flush=True); time.sleep(30)"), str(tmp_path / "locked" / ".writer.lock")], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(LogError, match="another process"):
            fresh.append(Measurement(trial=0, plan=ps[0]))
    finally:
        holder.kill()
        holder.wait()
    with pytest.raises(LogError, match="already exists"):
        LabLog.create(tmp_path / "run", "again")
    # a create killed before log.json was written leaves a skeleton that may be created again
    (tmp_path / "half" / "trials").mkdir(parents=True)
    (tmp_path / "half" / "trials.csv").write_text("trial,plan_hash,touchdown_x,touchdown_y,flags,message\n")
    assert len(LabLog.create(tmp_path / "half", "again")) == 0
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("someone's file")
    with pytest.raises(LogError, match="already exists"):
        LabLog.create(tmp_path / "other", "lab")


def test_corrupt_or_foreign_logs_are_named(tmp_path, lab):
    with pytest.raises(LogError, match="not found"):
        LabLog.open(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(LogError, match="no log.json"):
        LabLog.open(tmp_path / "empty")
    log = LabLog.create(tmp_path / "log", lab.description())
    run_plans(SafetyGate(lab), plans()[:1], log)
    header = json.loads((tmp_path / "log" / "log.json").read_text())
    header["version"] = 99
    (tmp_path / "log" / "log.json").write_text(json.dumps(header))
    with pytest.raises(LogError, match="version 99"):
        LabLog.open(tmp_path / "log")
    header["version"] = 1
    (tmp_path / "log" / "log.json").write_text(json.dumps(header))
    (tmp_path / "log" / "trials" / "000000" / "measurement.json").write_text("{not json")
    with pytest.raises(LogError, match="000000.measurement.json"):
        read_log(tmp_path / "log")
    (tmp_path / "log" / "trials" / "000000" / "measurement.json").unlink()
    with pytest.raises(LogError, match="missing"):
        read_log(tmp_path / "log")
    with pytest.raises(MeasurementError, match="touchdown"):
        Measurement(trial=0, plan=plans()[0], touchdown=[np.nan, 1.0])


def test_hidden_truth_never_appears_in_the_log(tmp_path, lab):
    log = LabLog.create(tmp_path / "log", SafetyGate(lab).description(), run={"seed": 11})
    run_plans(SafetyGate(lab), plans()[:3], log)
    m = log.measurement(0)
    assert m.touchdown is not None and m.ball_path is not None and m.joint_t is not None
    words = [*HIDDEN, "effects"]
    values = [v for eff in HIDDEN.values() for v in eff.values()]
    number = re.compile(r"-?\d+(?:\.\d+)?(?:e-?\d+)?")
    files = [p for p in (tmp_path / "log").rglob("*") if p.is_file()]
    assert len(files) >= 10
    for p in files:
        text = p.read_text()
        for w in words:
            assert w not in text, f"{w!r} leaked into {p}"
        for v in values:
            for scale in (1.0, 1000.0):  # m and mm
                hits = [x for x in number.findall(text) if float(x) == pytest.approx(v * scale, abs=1e-12)]
                assert not hits, f"hidden value {v} leaked into {p}"
