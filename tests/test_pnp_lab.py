"""The virtual pick-and-place lab: the scripted plan succeeds without effects, a hidden box offset spoils it, trials
are reproducible, the gate refuses plans over the limits, its log resumes after a kill, bad configs name the field."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from besdrake.cli import main
from besdrake.plan import MotionPlan
from besdrake.task import get_task
from besdrake.tasks.pick_and_place.lab import PickPlaceLab
from besdrake.tasks.pick_and_place.lab_config import HiddenEffects, parse_pick_place_lab_config
from besdrake.tasks.pick_and_place.measurement import PickPlaceMeasurement
from besdrake.transfer.lab import SafetyGate
from besdrake.transfer.lab_config import LabConfigError, open_lab
from besdrake.transfer.log import LabLog, LogError, read_log, run_plans
from besdrake.transfer.measurement import plan_hash
from besdrake.transfer.recorded_lab import RecordedLab

QUIET = {"placement_sd": 0.0, "placement_yaw_sd": 0.0, "pose_noise_sd": 0.0, "angle_noise_sd": 0.0, "encoder_noise_sd": 0.0}


def config(effects=None, noise=None, **top) -> dict:
    return {"name": "test_pnp_lab", "scenario": "pick_and_place", "seed": 0, "effects": effects or {},
            "noise": QUIET if noise is None else noise, **top}


@pytest.fixture(scope="module")
def ideal() -> PickPlaceLab:
    return PickPlaceLab(config())


@pytest.fixture(scope="module")
def scripted(ideal) -> MotionPlan:
    return get_task("pick_and_place").default_plan(ideal.rollout)


def like(lab: PickPlaceLab, **cfg) -> PickPlaceLab:
    """Another lab on the same Diagram."""
    return PickPlaceLab(config(**cfg), rollout=lab.rollout)


def still(lab: PickPlaceLab, duration: float = 0.2, scale: float = 0.0) -> MotionPlan:
    """A short plan that holds the home pose (the box stays on the shelf): cheap trials."""
    home = np.asarray(lab.robot.home, float)
    q = np.array([home, home + scale])
    return MotionPlan(t=[0.0, duration], q=q, qd=np.zeros_like(q), joint_names=lab.robot.joint_names, meta={"name": "still"})


def test_scripted_plan_succeeds_in_the_lab_without_effects(ideal, scripted):
    m = SafetyGate(ideal).execute(scripted, trial=0)
    assert isinstance(m, PickPlaceMeasurement)
    assert m.success and m.ok and m.raised_flags == [], m.message
    assert m.place_error < 0.01 and m.tilt < 0.05 and m.lift > 0.02 and m.slip < 0.01
    assert m.grasped and m.lifted and m.held and m.upright and m.on_table and m.collision == ""
    assert m.tracking_max.shape == (7,) and np.all(m.tracking_max < 0.05) and m.q_measured.shape[1] == 7
    assert np.linalg.norm(m.box_pose[:2] - m.place_target[:2]) == pytest.approx(m.place_error)


def test_a_hidden_box_offset_spoils_the_same_plan(ideal, scripted):
    base = ideal.execute(scripted, trial=0)
    off = like(ideal, effects={"box_pose_offset": {"x": 0.035}}).execute(scripted, trial=0)
    assert not off.success and "missed_place" in off.raised_flags, off.message
    assert off.place_error > base.place_error + 0.025, (base.place_error, off.place_error)
    sideways = like(ideal, effects={"box_pose_offset": {"y": 0.035}}).execute(scripted, trial=0)
    assert not sideways.success and not sideways.lifted and "not_lifted" in sideways.raised_flags, sideways.message


def test_hidden_pad_friction_acts_and_does_not_leak_into_the_next_trial(ideal, scripted):
    slippery = like(ideal, effects={"pad_friction": 0.01, "box_mass": 0.3}).execute(scripted, trial=0)
    assert not slippery.success and slippery.grasped and not slippery.lifted, slippery.message
    assert ideal.execute(scripted, trial=0).success, "the same Diagram without the effect grips again"


def test_trials_are_reproducible_by_index(ideal):
    lab = like(ideal, effects={"box_mass": 0.3}, noise={"placement_sd": 0.005, "pose_noise_sd": 0.001})
    plan = still(lab)
    a = lab.execute(plan, trial=3)
    b = lab.execute(plan, trial=4)
    again = lab.execute(plan, trial=3)
    np.testing.assert_array_equal(a.box_pose, again.box_pose)
    np.testing.assert_array_equal(a.q_measured, again.q_measured)
    assert not np.allclose(a.box_pose[:2], b.box_pose[:2], atol=1e-4), "another trial draws another placement"
    other_seed = PickPlaceLab(lab.config.with_seed(1), rollout=ideal.rollout).execute(plan, trial=3)
    assert not np.allclose(a.box_pose[:2], other_seed.box_pose[:2], atol=1e-4)
    assert "not_lifted" in a.raised_flags and not a.success  # the box stayed on the shelf


def test_the_gate_refuses_a_plan_over_the_limits_before_the_lab_sees_it(ideal, scripted):
    fast = MotionPlan(t=scripted.t / 4, q=scripted.q, qd=scripted.qd * 4, meta=dict(scripted.meta), joint_names=scripted.joint_names)
    seen = []

    class Spy(PickPlaceLab):
        def execute(self, plan, trial=None):
            seen.append(trial)
            return super().execute(plan, trial)

    gate = SafetyGate(Spy(config(), rollout=ideal.rollout))
    m = gate.execute(fast, trial=0)
    assert isinstance(m, PickPlaceMeasurement) and m.flags == {"refused_by_safety_gate": True}
    assert "velocity" in m.message and seen == [] and not m.success and m.box_pose is None
    # without the gate the robot's drives stop it: aborted, nothing simulated
    m = ideal.execute(fast, trial=1)
    assert m.flags == {"joint_limit_exceeded": True, "aborted": True} and m.joint_t is None


class KilledLab:
    """Wraps a lab and raises at trial ``kill_at`` (a process killed mid-run)."""

    def __init__(self, lab, kill_at: int) -> None:
        self.lab, self.kill_at, self.name, self.robot = lab, kill_at, lab.name, lab.robot
        self.measurement_type = lab.measurement_type
        self.executed: list[int] = []

    def execute(self, plan, trial=None):
        if trial == self.kill_at:
            raise KeyboardInterrupt("killed")
        self.executed.append(trial)
        return self.lab.execute(plan, trial=trial)


def test_a_killed_log_resumes_and_reads_back(tmp_path, ideal):
    lab = like(ideal, noise={"placement_sd": 0.004, "pose_noise_sd": 0.001, "encoder_noise_sd": 0.001})
    plans = [still(lab, 0.2), still(lab, 0.2, scale=10.0), still(lab, 0.3), still(lab, 0.25)]
    log = LabLog.create(tmp_path / "run", lab.description(), measurement=PickPlaceMeasurement)
    first = KilledLab(lab, kill_at=2)
    with pytest.raises(KeyboardInterrupt):
        run_plans(SafetyGate(first), plans, log)
    reopened = LabLog.open(tmp_path / "run")
    assert len(reopened) == 2 and reopened.measurement_type is PickPlaceMeasurement
    second = KilledLab(lab, kill_at=-1)
    summary = run_plans(SafetyGate(second), plans, reopened)
    assert summary.skipped == 2 and summary.total == 4
    assert first.executed == [0] and second.executed == [2, 3], "trial 1 is refused by the gate; none is run twice"
    got = read_log(tmp_path / "run")
    assert [type(m) for m in got] == [PickPlaceMeasurement] * 4
    assert got[1].flags == {"refused_by_safety_gate": True}
    direct = lab.execute(plans[3], trial=3)
    np.testing.assert_array_equal(got[3].box_pose, direct.box_pose)
    np.testing.assert_allclose(got[3].q_measured, direct.q_measured)
    assert got[3].result_dict() == direct.result_dict()
    header = json.loads((tmp_path / "run" / "log.json").read_text())
    assert header["version"] == 2 and header["task"] == "pick_and_place"
    assert (tmp_path / "run" / "trials.csv").read_text().splitlines()[0] == \
        "trial,plan_hash,success,place_error,tilt,box_x,box_y,box_z,box_yaw,flags,message"
    replay = SafetyGate(RecordedLab(tmp_path / "run"))
    assert replay.execute(plans[3], trial=0).result_dict() == direct.result_dict()
    assert isinstance(replay.execute(plans[1], trial=1), PickPlaceMeasurement)
    with pytest.raises(LogError, match="cannot append"):
        from besdrake.transfer.measurement import Measurement

        reopened.append(Measurement(trial=4, plan=plans[0]))


def test_the_log_keeps_no_hidden_truth(tmp_path, ideal):
    lab = like(ideal, effects={"box_pose_offset": {"x": 0.0123, "yaw": 0.0456}, "box_mass": 0.321, "pad_friction": 0.654})
    log = LabLog.create(tmp_path / "log", SafetyGate(lab).description(), measurement=lab.measurement_type)
    run_plans(lab, [still(lab)], log)
    text = " ".join(p.read_text() for p in (tmp_path / "log").rglob("*.json"))
    for secret in ("0.0123", "0.0456", "0.321", "0.654", "pad_friction", "box_mass", "box_pose_offset"):
        assert secret not in text


def test_plan_hash_covers_the_gripper_command(scripted):
    other = dict(scripted.meta)
    other["gripper"] = {"t": scripted.meta["gripper"]["t"], "width": [0.1] * len(scripted.meta["gripper"]["t"])}
    changed = MotionPlan(t=scripted.t, q=scripted.q, qd=scripted.qd, meta=other, joint_names=scripted.joint_names)
    renamed = MotionPlan(t=scripted.t, q=scripted.q, qd=scripted.qd, meta={**scripted.meta, "name": "x"}, joint_names=scripted.joint_names)
    bare = MotionPlan(t=scripted.t, q=scripted.q, qd=scripted.qd)
    assert plan_hash(changed) != plan_hash(scripted) == plan_hash(renamed) != plan_hash(bare)


def test_labs_open_by_name_for_either_task():
    from besdrake.tasks.throwing.lab import VirtualLab

    assert isinstance(open_lab("default_lab"), VirtualLab)
    lab = open_lab("pick_and_place_lab", seed=7)
    assert isinstance(lab, PickPlaceLab) and lab.config.seed == 7 and lab.robot.name == "iiwa14"
    assert lab.config.effects != HiddenEffects(), "the shipped lab hides effects"
    assert get_task("pick_and_place").default_lab == "pick_and_place_lab" and get_task("throwing").default_lab == "default_lab"


@pytest.mark.parametrize("mutate, field", [
    (lambda c: c["effects"].update(box_mass=-1.0), "effects.box_mass"),
    (lambda c: c["effects"].update(pad_friction="high"), "effects.pad_friction"),
    (lambda c: c["effects"].update(box_pose_offset={"x": 0.5}), "effects.box_pose_offset.x"),
    (lambda c: c["effects"].update(box_pose_offset={"z": 0.01}), "box_pose_offset has unknown"),
    (lambda c: c["effects"].update(wind=1.0), "unknown effect"),
    (lambda c: c["noise"].update(pose_noise_sd=float("nan")), "noise.pose_noise_sd"),
    (lambda c: c["noise"].update(joint_rate_hz=0), "noise.joint_rate_hz"),
    (lambda c: c.update(seed=-2), "seed"),
    (lambda c: c.update(robot="no_such_robot"), "robot"),
    (lambda c: c.update(scenario="nominal"), "scenario"),
    (lambda c: c.update(home_pose=[0.0] * 6), "home_pose"),
    (lambda c: c.update(record_joints="yes"), "record_joints"),
    (lambda c: c.update(colour="blue"), "unknown field"),
])
def test_bad_config_values_name_the_field(mutate, field):
    cfg = config(effects={}, noise={})
    mutate(cfg)
    with pytest.raises(LabConfigError, match=field.replace(".", r"\.")):
        parse_pick_place_lab_config(cfg)


def test_lab_run_cli_fills_a_pick_and_place_log_and_names_bad_fields(tmp_path, capsys, ideal):
    lab_file = tmp_path / "my_lab.yaml"
    lab_file.write_text(yaml.safe_dump(config(noise={"placement_sd": 0.002})))
    plans = tmp_path / "plans.json"
    plans.write_text(json.dumps([still(ideal).to_dict(), still(ideal, 0.3).to_dict()]))
    args = ["lab", "run", "--lab", str(lab_file), "--plans", str(plans), "--out", str(tmp_path / "log"), "--quiet"]
    assert main(args) == 0
    first = json.loads(capsys.readouterr().out)
    assert first["flag_counts"] == {"missed_place": 2, "not_lifted": 2} and first["successes"] == 0
    assert main(args) == 0 and json.loads(capsys.readouterr().out)["resumed_after"] == 2
    # the diagnosis reads the log through the pick-and-place task (too few picks here: one error line)
    assert main(["diagnose", str(tmp_path / "log")]) == 2 and "only 2 usable picks" in capsys.readouterr().err
    bad = config()
    bad["effects"] = {"box_mass": 99}
    lab_file.write_text(yaml.safe_dump(bad))
    assert main([*args[:-3], "--out", str(tmp_path / "log2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("besdrake: error:") and "my_lab.yaml" in err[0] and "effects.box_mass" in err[0]
