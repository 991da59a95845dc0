"""The lab interface: safety gate, virtual lab (noise, placement, capture volume, aborts), plugins, recorded lab."""

from __future__ import annotations

import dataclasses

from pathlib import Path

import numpy as np
import pytest

from besdrake.plan import MotionPlan
from besdrake.tasks.throwing.throws import default_throw
from besdrake.transfer.lab import JointLimits, Lab, SafetyGate
from besdrake.transfer.log import LabLog, run_plans
from besdrake.tasks.throwing.measurement import ThrowMeasurement as Measurement
from besdrake.plugins import PluginError, load_plugin
from besdrake.transfer.recorded_lab import PlanNotRecordedError, RecordedLab
from besdrake.tasks.throwing.lab import LabConfigError, VirtualLab, load_lab_config, parse_lab_config


from besdrake.robot import load_robot

COMPI = load_robot("compi")


def lab_config(**noise):
    base = {"touchdown_sd": 0.0, "ball_placement_sd": 0.0, "mocap_noise_sd": 0.0, "mocap_dropout": 0.0, "encoder_noise_sd": 0.0}
    base.update(noise)
    return {"name": "test_lab", "scenario": "nominal", "seed": 7, "effects": {}, "noise": base}


@pytest.fixture(scope="module")
def quiet_lab() -> VirtualLab:
    """A noise-free virtual lab; tests swap its config's noise (the Drake diagram is built once)."""
    return VirtualLab(parse_lab_config(lab_config()))


def with_noise(lab: VirtualLab, **noise) -> VirtualLab:
    lab.config = parse_lab_config(lab_config(**noise))
    return lab


def pooled_sd(points: np.ndarray) -> float:
    return float(np.sqrt(np.var(points, axis=0, ddof=1).mean()))


# ---------------------------------------------------------------------------------------- safety gate


class SpyLab:
    """A lab that records what reached it."""

    name = "spy"

    robot = COMPI
    measurement_type = Measurement  # a throwing lab's (the gate's refusals are of this class)

    def __init__(self) -> None:
        self.calls: list[int] = []

    def description(self) -> dict:
        return {"name": self.name}

    def execute(self, plan: MotionPlan, trial: int | None = None) -> Measurement:
        self.calls.append(trial)
        return Measurement(trial=trial, plan=plan, touchdown=np.array([1.0, 0.0]))


def test_spy_and_virtual_lab_satisfy_the_protocol(quiet_lab):
    assert isinstance(SpyLab(), Lab)
    assert isinstance(quiet_lab, Lab)
    assert isinstance(SafetyGate(SpyLab()), Lab)


@pytest.mark.parametrize(
    "kind, plan",
    [
        ("position", MotionPlan(t=[0.0, 1.0], q=np.tile([0.0, 2.2, 0.0, 0.0, 0.0, 0.0], (2, 1)))),
        ("velocity", default_throw(1.5)),  # peak acceleration 19 rad/s^2 (allowed), peak speed ~3.6 rad/s
        ("acceleration", default_throw(0.35, accel=30.0)),  # slow enough, but 30 rad/s^2
    ],
)
def test_gate_refuses_each_kind_of_limit_before_running(kind, plan):
    report = plan.check_limits(COMPI.limits)
    kinds = {k for k in ("position", "velocity", "acceleration") if np.any(getattr(report, k) > 0)}
    assert kinds == {kind}, "the test plan must violate exactly one kind of limit"
    spy = SpyLab()
    gate = SafetyGate(spy)
    m = gate.execute(plan)
    assert spy.calls == [], "a refused plan must never reach the lab"
    assert m.flags == {"refused_by_safety_gate": True}
    assert kind in m.message and "joint" in m.message
    assert m.touchdown is None and m.joint_t is None and m.ball_t is None
    # a plan within the limits passes, and trial numbers keep counting
    ok = gate.execute(default_throw(0.35))
    assert spy.calls == [1] and ok.trial == 1 and not ok.flags


def test_gate_refuses_a_malformed_plan_and_honours_custom_limits():
    spy = SpyLab()
    bad = MotionPlan(t=[0.0, 1.0], q=np.full((2, 6), np.nan))
    m = SafetyGate(spy).execute(bad)
    assert m.flags["refused_by_safety_gate"] and "malformed" in m.message and spy.calls == []
    tight = dataclasses.replace(COMPI.limits, velocity=np.full(6, 0.5))
    m2 = SafetyGate(spy, limits=tight).execute(default_throw(0.35))
    assert m2.flags.get("refused_by_safety_gate") and "velocity" in m2.message and spy.calls == []
    with pytest.raises(ValueError, match="velocity"):
        dataclasses.replace(COMPI.limits, velocity=np.full(6, -1.0))
    with pytest.raises(TypeError, match="robot"):
        SafetyGate(type("NoRobotLab", (), {"execute": lambda self, plan, trial=None: None})())


# ---------------------------------------------------------------------------------------- virtual lab


def test_noise_sd_of_repeated_good_throws_is_in_the_papers_range(quiet_lab):
    """Default noise (touchdown_sd 5 cm + 2 mm ball placement): SD of 40 repetitions within 4.5-7 cm."""
    lab = with_noise(quiet_lab, touchdown_sd=0.05, ball_placement_sd=0.002, mocap_noise_sd=0.001)
    plan = default_throw(0.35)
    td = np.array([lab.execute(plan, trial=k).touchdown for k in range(40)])
    sd = pooled_sd(td)
    assert 0.045 <= sd <= 0.07, sd


def test_configured_touchdown_sd_is_honoured(quiet_lab):
    """Without placement variation the scatter is the configured SD (40 trials: +-25%, about 3 standard errors)."""
    lab = with_noise(quiet_lab, touchdown_sd=0.03)
    plan = default_throw(0.35)
    td = np.array([lab.execute(plan, trial=k).touchdown for k in range(40)])
    assert abs(pooled_sd(td) / 0.03 - 1.0) < 0.25


def test_ball_placement_changes_the_throw_physically(quiet_lab):
    plan = default_throw(0.35)
    lab = with_noise(quiet_lab)
    fixed = np.array([lab.execute(plan, trial=k).touchdown for k in range(3)])
    assert np.ptp(fixed, axis=0).max() == 0.0, "no noise configured: every trial lands on the same spot"
    lab = with_noise(quiet_lab, ball_placement_sd=0.002)
    ms = [lab.execute(plan, trial=k) for k in range(8)]
    td = np.array([m.touchdown for m in ms])
    assert pooled_sd(td) > 0.003, "a 2 mm placement scatter must move the touchdown by millimetres at least"
    starts = np.array([m.ball_path[0] for m in ms])
    assert np.ptp(starts[:, :2], axis=0).max() > 1e-4, "the ball starts at a different spot in the scoop"


def test_trial_k_measures_the_same_whenever_run(quiet_lab):
    lab = with_noise(quiet_lab, touchdown_sd=0.05, ball_placement_sd=0.002, mocap_noise_sd=0.001, mocap_dropout=0.05, encoder_noise_sd=0.001)
    plan = default_throw(0.3)
    a, b, c = lab.execute(plan, trial=5), lab.execute(plan, trial=6), lab.execute(plan, trial=5)
    np.testing.assert_array_equal(a.touchdown, c.touchdown)
    np.testing.assert_array_equal(a.ball_path, c.ball_path)
    np.testing.assert_array_equal(a.q_measured, c.q_measured)
    assert not np.array_equal(a.touchdown, b.touchdown)
    assert np.isnan(a.ball_path).any(axis=1).sum() > 0, "5% dropouts must leave gaps"
    # encoder noise is there, and the commanded trajectory is the plan
    np.testing.assert_allclose(a.q_commanded, plan.sample(a.joint_t))
    clean = with_noise(lab, touchdown_sd=0.05, ball_placement_sd=0.002).execute(plan, trial=5)
    enc = a.q_measured - clean.q_measured  # same trial, same placement: only the encoder noise differs
    assert np.std(enc) == pytest.approx(0.001, rel=0.1)
    assert a.meta["lab"] == "test_lab" and a.meta["mocap_rate_hz"] == 200.0


def test_capture_volume_limits_the_ball_path_and_the_touchdown(quiet_lab):
    lab = with_noise(quiet_lab)
    plan = default_throw(0.5)  # lands ~2.25 m away
    seen = lab.execute(plan, trial=0)
    assert seen.touchdown is not None and not seen.flags
    dt = np.diff(seen.ball_t)
    np.testing.assert_allclose(dt, 1 / 200.0, atol=1e-12)
    cfg = lab_config()
    cfg["noise"]["capture_volume"] = {"min": [-0.5, -1.0, 0.0], "max": [1.5, 1.0, 3.0]}
    lab.config = parse_lab_config(cfg)
    m = lab.execute(plan, trial=0)
    assert m.touchdown is None and m.flags == {"ball_not_seen": True}
    assert len(m.ball_t) < len(seen.ball_t) and np.all(m.ball_path[:, 0] <= 1.5)


def test_recording_switches_and_hidden_effect_acts(quiet_lab):
    plan = default_throw(0.35)
    nominal = with_noise(quiet_lab).execute(plan, trial=0)
    cfg = lab_config()
    cfg.update(record_ball_path=False, record_joints=False, effects={"base_offset": {"z": -0.1}})
    quiet_lab.config = parse_lab_config(cfg)
    m = quiet_lab.execute(plan, trial=0)
    assert m.ball_t is None and m.ball_path is None and m.joint_t is None and m.q_measured is None
    assert m.touchdown[0] < nominal.touchdown[0] - 0.02, "a 10 cm lower base throws shorter"


def test_measured_joint_beyond_limit_aborts_the_run(quiet_lab):
    """The gate passes the plan (1.98 rad < 2.0), but a hidden encoder offset drives joint5 to ~2.03 rad."""
    plan = default_throw(0.35)
    plan.q[:, 4] += 1.98 - plan.q[:, 4].max()
    assert plan.check_limits(COMPI.limits).ok
    cfg = lab_config()
    cfg["effects"] = {"joint_offset": {"joint5": 0.05}}
    quiet_lab.config = parse_lab_config(cfg)
    m = SafetyGate(quiet_lab).execute(plan)
    assert m.flags.get("aborted") and m.flags.get("joint_limit_exceeded")
    assert m.touchdown is None and "switched itself off" in m.message


def test_without_the_gate_a_plan_over_the_limits_aborts_the_run(quiet_lab):
    m = with_noise(quiet_lab).execute(default_throw(0.35, accel=30.0), trial=0)
    assert m.flags == {"joint_limit_exceeded": True, "aborted": True}
    assert "acceleration" in m.message and m.touchdown is None and m.joint_t is None


def test_lab_config_errors_name_the_problem(tmp_path):
    with pytest.raises(LabConfigError, match="not found"):
        load_lab_config(tmp_path / "missing.yaml")
    (tmp_path / "bad.yaml").write_text("name: [unclosed\n")
    with pytest.raises(LabConfigError, match="not valid YAML"):
        load_lab_config(tmp_path / "bad.yaml")
    for mutate, pattern in [
        (lambda c: c["noise"].update(touchdown_sd=float("nan")), "touchdown_sd"),
        (lambda c: c["noise"].update(mocap_rate_hz=-5), "mocap_rate_hz"),
        (lambda c: c["noise"].update(capture_volume={"min": [0, 0, 0], "max": [1, -1, 1]}), "capture_volume"),
        (lambda c: c.update(effects={"no_such_effect": {}}), "no_such_effect"),
        (lambda c: c.update(effects={"base_offset": {"z": 5.0}}), "outside its bounds"),
        (lambda c: c.update(seed=-1), "seed"),
        (lambda c: c.update(colour="blue"), "unknown field"),
        (lambda c: c.update(record_joints="yes"), "record_joints"),
    ]:
        cfg = lab_config()
        mutate(cfg)
        with pytest.raises(LabConfigError, match=pattern):
            parse_lab_config(cfg)


def test_shipped_lab_configs_load():
    from pathlib import Path

    labs = sorted((Path(__file__).resolve().parents[1] / "besdrake" / "diagrams" / "labs").glob("*.yaml"))
    assert {p.stem for p in labs} >= {"default_lab", "touchdown_only_lab"}
    from besdrake.transfer.lab_config import lab_task, read_lab_yaml

    for p in labs:
        if lab_task(read_lab_yaml(p)[0], p.parent) != "throwing":
            continue  # another task's lab (tests/test_pnp_lab.py)
        cfg = load_lab_config(p)
        assert cfg.name == p.stem
    only = load_lab_config(labs[[p.stem for p in labs].index("touchdown_only_lab")])
    assert not only.record_ball_path and not only.record_joints
    default = load_lab_config(labs[[p.stem for p in labs].index("default_lab")])
    assert default.effects["base_offset"]["z"] == pytest.approx(-0.03)


def test_the_default_lab_path_works_from_any_working_folder(tmp_path, monkeypatch):
    # besdrake learn's default (diagrams/labs/default_lab.yaml) from outside the checkout: found in the checkout
    monkeypatch.chdir(tmp_path)
    assert load_lab_config("diagrams/labs/default_lab.yaml").name == "default_lab"
    mine = tmp_path / "diagrams" / "labs" / "default_lab.yaml"  # a file of the same path in the working folder wins
    mine.parent.mkdir(parents=True)
    mine.write_text((Path(__file__).resolve().parents[1] / "besdrake" / "diagrams" / "labs" / "default_lab.yaml").read_text().replace(
        "name: default_lab", "name: my_lab"))
    assert load_lab_config("diagrams/labs/default_lab.yaml").name == "my_lab"
    with pytest.raises(LabConfigError, match="not found"):
        load_lab_config("diagrams/labs/no_such_lab.yaml")


# ---------------------------------------------------------------------------------------- plugins


def test_plugin_loads_and_its_effect_acts(drag_plugin, quiet_lab):
    path, name = drag_plugin
    cfg = lab_config()
    cfg["plugins"] = [path.name]  # relative to the config file
    cfg["effects"] = {name: {"cd": 0.8}}
    import yaml

    (path.parent / "lab.yaml").write_text(yaml.safe_dump(cfg))
    loaded = load_lab_config(path.parent / "lab.yaml")
    assert loaded.effects == {name: {"cd": 0.8}}
    plan = default_throw(0.35)
    base = with_noise(quiet_lab).execute(plan, trial=0).touchdown
    quiet_lab.config = loaded
    dragged = quiet_lab.execute(plan, trial=0).touchdown
    assert dragged[0] < base[0] - 0.02, "drag must shorten the throw"
    assert load_plugin(path) is load_plugin(path), "loaded once"


def test_plugin_errors_name_the_file(tmp_path):
    with pytest.raises(PluginError, match="not found"):
        load_plugin(tmp_path / "nope.py")
    (tmp_path / "broken.py").write_text("def oops(:\n")
    with pytest.raises(PluginError, match="broken.py"):
        load_plugin(tmp_path / "broken.py")


# ---------------------------------------------------------------------------------------- recorded lab


def test_recorded_lab_replays_a_log(tmp_path, quiet_lab):
    lab = with_noise(quiet_lab, touchdown_sd=0.05, ball_placement_sd=0.002, mocap_noise_sd=0.001)
    a, b = default_throw(0.3), default_throw(0.4)
    log = LabLog.create(tmp_path / "log", lab.description())
    run_plans(SafetyGate(lab), [a, b, a], log)
    logged = log.measurements()
    rec = RecordedLab(tmp_path / "log")
    assert len(rec) == 3 and rec.has(a) and not rec.has(default_throw(0.45))
    renamed = MotionPlan(t=b.t.copy(), q=b.q.copy(), qd=b.qd.copy(), meta={"name": "same trajectory, other name"})
    mb = rec.execute(renamed)
    np.testing.assert_array_equal(mb.touchdown, logged[1].touchdown)
    np.testing.assert_array_equal(mb.q_measured, logged[1].q_measured)
    assert mb.meta["recorded_trial"] == 1 and mb.trial == 0
    # the plan logged twice replays its trials in order, then starts over
    r1, r2, r3 = rec.execute(a), rec.execute(a), rec.execute(a)
    assert [r.meta["recorded_trial"] for r in (r1, r2, r3)] == [0, 2, 0]
    np.testing.assert_array_equal(r2.touchdown, logged[2].touchdown)
    assert [r.trial for r in (r1, r2, r3)] == [1, 2, 3]
    with pytest.raises(PlanNotRecordedError, match="never executed"):
        rec.execute(default_throw(0.45))
    # a recorded lab can itself sit behind the gate and fill a new log
    log2 = LabLog.create(tmp_path / "replayed", SafetyGate(rec).description())
    run_plans(SafetyGate(RecordedLab(tmp_path / "log")), [b, a], log2)
    np.testing.assert_array_equal(log2.measurement(0).touchdown, logged[1].touchdown)


def test_placement_habit_plus_scatter_stays_within_the_effects_bounds(quiet_lab):
    """A hidden placement habit near the bound plus this trial's scatter must not leave the bounds
    (it raised EffectError in the diagnosis benchmark): the ball sits at the scoop's edge instead."""
    cfg = lab_config(ball_placement_sd=0.005)
    cfg["effects"] = {"ball_placement": {"x": 0.0075}}
    quiet_lab.config = parse_lab_config(cfg)
    try:
        for trial in range(6):
            m = quiet_lab.execute(default_throw(0.35), trial=trial)
            assert not m.flags.get("aborted") and m.touchdown is not None, m.message
    finally:
        with_noise(quiet_lab)
