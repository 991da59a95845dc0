"""Issue 26 part 3: no bad input loses data or crashes (one test per case), and the fuzzer's fast subset."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from besdrake.cli import main


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """A 300-frame synthetic recording (labelled rec.tsv, unlabelled unl.tsv, rec.c3d) and the default throw."""
    from besdrake.mocap.c3d_io import write_c3d
    from besdrake.mocap.qualisys import read_tsv, write_tsv
    from besdrake.tasks.throwing.demonstrator import generate_dataset
    from besdrake.tasks.throwing.throws import default_throw

    root = tmp_path_factory.mktemp("hardening")
    generate_dataset(root / "syn", n_subjects=1, n_experiments=1, n_throws=2, seed=0)
    rec = read_tsv(next((root / "syn").glob("*.tsv")))
    write_tsv(rec, root / "rec.tsv")
    write_c3d(rec, root / "rec.c3d")
    shutil.copy(next((root / "syn" / "unlabeled").glob("*.tsv")), root / "unl.tsv")
    default_throw().save(root / "plan.json")
    return root


def _error(capsys, argv: list[str]) -> str:
    """Run the CLI, expect exit 2 with exactly one 'besdrake: error:' line; return that line."""
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("besdrake: error:")]
    assert rc == 2, err
    assert len(lines) == 1 and "internal error" not in lines[0] and "Traceback" not in err, err
    return lines[0]


def _edit_tsv(src: Path, dst: Path, edit) -> Path:
    """Copy a TSV, applying ``edit(row_index, fields) -> fields`` to each data row."""
    lines = src.read_text().splitlines()
    head = next(i for i, ln in enumerate(lines) if ln.startswith("Frame"))
    rows = [edit(k, ln.split("\t")) for k, ln in enumerate(lines[head + 1 :])]
    dst.write_text("\n".join(lines[: head + 1] + ["\t".join(r) for r in rows]) + "\n")
    return dst


# ---------------------------------------------------------------------------------------- data loss


def test_label_refuses_out_equal_to_an_input(data, tmp_path, capsys):
    unl = shutil.copy(data / "unl.tsv", tmp_path / "unl.tsv")
    before = Path(unl).read_bytes()
    for out in (unl, tmp_path / "." / "unl.tsv", data / "rec.tsv"):
        line = _error(capsys, ["mocap", "label", unl, "--reference", data / "rec.tsv", "--out", out])
        assert "is an input file" in line
    assert Path(unl).read_bytes() == before


def test_label_out_into_missing_folder(data, tmp_path, capsys):
    line = _error(capsys, ["mocap", "label", data / "unl.tsv", "--reference", data / "rec.tsv", "--out", tmp_path / "no" / "x.tsv"])
    assert "does not exist" in line


def test_atomic_write_leaves_no_partial_file(tmp_path):
    from besdrake._io import atomic_path, write_json

    target = tmp_path / "a.json"
    write_json(target, {"a": 1})
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("killed")
    assert json.loads(target.read_text()) == {"a": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


# ---------------------------------------------------------------------------------------- exposed


def test_meshcat_listens_on_localhost_by_default(monkeypatch, tmp_path):
    import pydrake.geometry as geometry

    from besdrake.sim.cliutil import add_common_arguments
    from besdrake.sim.record import record_html
    from besdrake.tasks.throwing.throws import default_throw

    hosts = []
    real = geometry.Meshcat

    def spy(params=None):
        hosts.append(params.host if params is not None else "*")
        return real(params) if params is not None else real()

    monkeypatch.setattr(geometry, "Meshcat", spy)
    record_html(default_throw(), tmp_path / "r.html", limits="flag")
    assert hosts == ["localhost"]
    import argparse

    p = argparse.ArgumentParser()
    add_common_arguments(p)
    assert p.parse_args([]).meshcat_host == "localhost"
    assert p.parse_args(["--meshcat-host", "0.0.0.0"]).meshcat_host == "0.0.0.0"


# ---------------------------------------------------------------------------------------- safety gate


def _plan_variants():
    from besdrake.plan import MotionPlan
    from besdrake.tasks.throwing.throws import default_throw

    p = default_throw()
    long = MotionPlan(t=np.append(p.t, 3600.0), q=np.vstack([p.q, p.q[-1:]]))
    close = MotionPlan(t=np.append(p.t, p.t[-1] + 150e-9), q=np.vstack([p.q, p.q[-1:]]))
    return p, long, close


def test_gate_refuses_long_plans_close_knots_and_a_far_start():
    from besdrake.tasks.throwing.throws import START_POSE
    from besdrake.transfer.lab import SafetyGate, SafetyLimits
    from besdrake.tasks.throwing.lab import VirtualLab, load_lab_config

    p, long, close = _plan_variants()
    gate = SafetyGate(VirtualLab(load_lab_config("ideal_lab")))
    assert gate.check(p) == []
    assert "longer than the maximum 30 s" in gate.check(long)[0]
    assert "closer than the control period" in gate.check(close)[0]
    m = gate.execute(long)
    assert m.flags["refused_by_safety_gate"]
    home = VirtualLab(dataclasses.replace(load_lab_config("ideal_lab"), home_pose=tuple(START_POSE)))
    gate = SafetyGate(home)
    far = dataclasses.replace(p, q=p.q + np.array([1.0, 0, 0, 0, 0, 0]))
    assert "1 rad from the robot's current pose at joint 1" in gate.check(far)[0]
    assert gate.check(p) == []
    assert SafetyGate(home, safety=SafetyLimits(start_tolerance_rad=1.5)).check(far) == []
    with pytest.raises(ValueError):
        SafetyLimits(max_duration_s=float("nan"))


def test_simulate_refuses_the_gates_plans(tmp_path, capsys):
    _, long, close = _plan_variants()
    for name, plan in (("long", long), ("close", close)):
        path = plan.save(tmp_path / f"{name}.plan.json")
        assert "refused by the safety gate" in _error(capsys, ["simulate", "--plan", path, "--json"])


# ---------------------------------------------------------------------------------------- silently wrong


def test_centimetre_files_are_named(data, tmp_path, capsys):
    def to_cm(k, f):
        return f[:2] + [x if x == "null" else f"{float(x) / 10:.3f}" for x in f[2:]]

    cm = _edit_tsv(data / "rec.tsv", tmp_path / "cm.tsv", to_cm)
    assert "centimetres" in _error(capsys, ["segment", cm, "--json"])
    cm_unl = _edit_tsv(data / "unl.tsv", tmp_path / "cm_unl.tsv", to_cm)
    assert "centimetres" in _error(capsys, ["mocap", "label", cm_unl, "--reference", data / "rec.tsv", "--out", tmp_path / "o.tsv"])


def test_truncated_last_number_or_line(data, tmp_path, capsys):
    lines = (data / "rec.tsv").read_text().rstrip("\n").split("\n")
    last = lines[-1].split("\t")
    k = max(i for i, v in enumerate(last) if v != "null")
    cut = lines[:-1] + ["\t".join(last[: k] + [last[k][:-2]])]
    (tmp_path / "num.tsv").write_text("\n".join(cut))
    assert "truncated" in _error(capsys, ["segment", tmp_path / "num.tsv"])
    (tmp_path / "line.tsv").write_text("\n".join(lines[:-1] + [lines[-1][: len(lines[-1]) // 2]]))
    assert "truncated" in _error(capsys, ["segment", tmp_path / "line.tsv"])


def test_glitch_sample_is_rejected_with_a_warning(data, tmp_path, capsys):
    def glitch(k, f):
        if k == 200:
            f = list(f)
            f[2] = f"{float(f[2]) + 10000.0:.3f}"  # Back top x + 10 m
        return f

    bad = _edit_tsv(data / "rec.tsv", tmp_path / "glitch.tsv", glitch)
    assert main(["segment", str(data / "rec.tsv"), "--json"]) == 0
    clean = json.loads(capsys.readouterr().out)
    assert main(["segment", str(bad), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert any("rejected as glitches" in w and "frame 201" in w for w in got["warnings"])
    assert len(got["segments"]) == len(clean["segments"])


def test_truncated_c3d_is_refused(data, tmp_path, capsys):
    raw = (data / "rec.c3d").read_bytes()
    (tmp_path / "t.c3d").write_bytes(raw[: len(raw) // 2])
    assert "truncated C3D file" in _error(capsys, ["segment", tmp_path / "t.c3d"])


def test_lab_log_detects_edited_and_deleted_trials(data, tmp_path, capsys):
    from besdrake.transfer.log import LabLog, LogError

    argv = ["lab", "run", "--lab", "ideal_lab", "--plans", data / "plan.json", "--out", tmp_path / "log", "--quiet"]
    assert main([str(a) for a in argv]) == 0
    capsys.readouterr()
    m = tmp_path / "log" / "trials" / "000000" / "measurement.json"
    text = m.read_text()
    info = json.loads(text)
    info["touchdown"][0] += 0.1  # a hand-edited but valid number
    m.write_text(json.dumps(info, indent=1) + "\n")
    with pytest.raises(LogError, match="changed after the trial was logged"):
        LabLog.open(tmp_path / "log").measurement(0)
    assert "changed after the trial was logged" in _error(capsys, argv)
    m.write_text(text)
    shutil.rmtree(m.parent)
    assert "folder" in _error(capsys, argv) and "missing" in _error(capsys, argv)


def test_run_folder_detects_edited_stage_files(tmp_path):
    from besdrake.pipeline.run import RunError, RunFolder

    run = RunFolder(tmp_path / "run", {"a": 1})
    d = run.stage_dir(1, "label")
    (d / "x.json").write_text('{"v": 1}')
    run.mark_done(1, "label", {}, 0.1)
    assert run.done(1, "label")["files"]
    (d / "x.json").write_text('{"v": 2}')
    with pytest.raises(RunError, match="was changed after the stage finished"):
        run.done(1, "label")
    (d / "x.json").unlink()
    with pytest.raises(RunError, match="was deleted"):
        run.done(1, "label")


# ---------------------------------------------------------------------------------------- tracebacks


def test_decreasing_time_is_an_error(data, tmp_path, capsys):
    def back(k, f):
        return f[:1] + ["0.00001"] + f[2:] if k == 50 else f

    bad = _edit_tsv(data / "rec.tsv", tmp_path / "dec.tsv", back)
    assert "Time must increase" in _error(capsys, ["segment", bad])
    assert "Time must increase" in _error(capsys, ["mocap", "label", data / "unl.tsv", "--reference", bad, "--out", tmp_path / "o.tsv"])
    folder = tmp_path / "demos"
    folder.mkdir()
    shutil.copy(bad, folder / "dec.tsv")
    assert "Time must increase" in _error(capsys, ["learn", "--quick", "--demonstrations", folder, "--out", tmp_path / "run", "--stage", "label"])


def test_all_markers_null(data, tmp_path, capsys):
    null = _edit_tsv(data / "unl.tsv", tmp_path / "null.tsv", lambda k, f: f[:2] + ["null"] * (len(f) - 2))
    assert "no marker is visible" in _error(capsys, ["mocap", "label", null, "--reference", data / "rec.tsv", "--out", tmp_path / "o.tsv"])
    null_l = _edit_tsv(data / "rec.tsv", tmp_path / "null_l.tsv", lambda k, f: f[:2] + ["null"] * (len(f) - 2))
    assert "never visible" in _error(capsys, ["segment", null_l])


def test_c3d_with_corrupt_parameters(data, tmp_path, capsys):
    raw = bytearray((data / "rec.c3d").read_bytes())
    raw[512:1024] = bytes((i * 37) % 256 for i in range(512))  # the parameter section
    (tmp_path / "p.c3d").write_bytes(bytes(raw))
    _error(capsys, ["segment", tmp_path / "p.c3d"])


@pytest.mark.parametrize("value", ["-1", "nan"])
def test_max_gap_must_be_a_nonnegative_number(data, tmp_path, capsys, value):
    assert "--max-gap" in _error(capsys, ["mocap", "label", data / "unl.tsv", "--reference", data / "rec.tsv", "--out", tmp_path / "o.tsv", "--max-gap", value])
    assert "gap" in _error(capsys, ["segment", data / "rec.tsv", "--max-gap", value])


def test_scenario_without_ball_body(tmp_path, capsys):
    from besdrake.sim.scenario import DIAGRAMS_DIR

    text = (DIAGRAMS_DIR / "nominal.yaml").read_text()
    ball = next(ln.split(":", 1)[1].split("#")[0].strip() for ln in text.splitlines() if ln.strip().startswith("ball:"))
    from besdrake.sim.scenario import resolve_model_uri

    sdf = resolve_model_uri(ball).read_text().replace('name="ball"', 'name="sphere"')
    (tmp_path / "noball.sdf").write_text(sdf)
    (tmp_path / "s.yaml").write_text(text.replace(ball, str(tmp_path / "noball.sdf")))
    assert "ball" in _error(capsys, ["simulate", "--scenario", tmp_path / "s.yaml", "--json"])


def test_lab_naming_a_missing_scenario(data, tmp_path, capsys):
    (tmp_path / "lab.yaml").write_text("name: x\nscenario: no_such_scenario\n")
    assert "no_such_scenario" in _error(capsys, ["lab", "run", "--lab", tmp_path / "lab.yaml", "--plans", data / "plan.json", "--out", tmp_path / "log"])


@pytest.mark.parametrize("body", ["raise RuntimeError('boom')", "import sys; sys.exit(3)"])
def test_plugin_failing_in_apply(data, tmp_path, capsys, body):
    from besdrake.sim.effects import unregister_effect

    name = f"failing_{abs(hash(body)) % 10**6}"
    (tmp_path / "p.py").write_text(
        "from besdrake.sim.effects import Effect, Param, register_effect\n"
        "@register_effect\nclass F(Effect):\n    '''test'''\n"
        f"    name = '{name}'\n    applied_via = 'flight'\n    params = {{'cd': Param(0.0, 0.0, 1.0, '1', 'x')}}\n"
        f"    def apply(self, setup, values):\n        {body}\n")
    (tmp_path / "lab.yaml").write_text(f"name: x\nplugins: [p.py]\neffects:\n  {name}: {{cd: 0.1}}\n")
    try:
        line = _error(capsys, ["lab", "run", "--lab", tmp_path / "lab.yaml", "--plans", data / "plan.json", "--out", tmp_path / "log"])
    finally:
        unregister_effect(name)
    assert name in line and ("boom" in line or "sys.exit(3)" in line)


def test_plugin_calling_sys_exit_at_import(data, tmp_path, capsys):
    (tmp_path / "p.py").write_text("import sys\nsys.exit(3)\n")
    line = _error(capsys, ["lab", "run", "--lab", "ideal_lab", "--plugin", tmp_path / "p.py", "--plans", data / "plan.json", "--out", tmp_path / "log"])
    assert "SystemExit" in line


@pytest.mark.parametrize("content", ["", "Frame\tTime\n1\t0\n", "\x00\x01binary", "MARKER_NAMES\ta\nFREQUENCY\t100\n1\t2\n"])
def test_learn_demonstrations_malformed(tmp_path, capsys, content):
    folder = tmp_path / "demos"
    folder.mkdir()
    (folder / "bad.tsv").write_text(content)
    _error(capsys, ["learn", "--quick", "--demonstrations", folder, "--out", tmp_path / "run", "--stage", "label"])


def test_internal_error_is_one_line_and_a_report_file(monkeypatch, capsys):
    import besdrake.commands.simulate as sim

    def broken(args):
        raise KeyError("bug")

    monkeypatch.setattr(sim, "run", broken)
    monkeypatch.delenv("BESDRAKE_DEBUG", raising=False)
    rc = main(["simulate"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "internal error (KeyError" in err[0] and "please report" in err[0]
    report = Path(err[0].split("traceback in ")[1].split(" ")[0])
    assert "Traceback" in report.read_text()
    report.unlink()


def test_simulate_refuses_a_robot_that_cannot_do_the_task(capsys):
    """A gripper arm on the throwing scenario: one error line naming the missing scoop (was an internal error,
    the Diagram's plan source and the arm's desired-state port of different sizes)."""
    from besdrake.sim.scenario import MODELS_DIR

    assert main(["simulate", "--robot", str(MODELS_DIR / "iiwa14" / "robot.yaml"), "--json"]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("besdrake: error:")]
    assert len(err) == 1 and "a scoop needs" in err[0] and "internal error" not in err[0]


def test_an_actuator_or_scoop_value_of_the_wrong_type_is_one_error_line(tmp_path, capsys):
    """Found by the fuzzer: a number or list as a joint's or the gripper's actuator reached Drake, a list as a scoop
    dimension float() (internal errors)."""
    import yaml

    from besdrake.sim.scenario import MODELS_DIR

    for robot, edit, field in (("compi", lambda d: d["joints"][3].update(actuator=[1, 2]), "joints[3].actuator"),
                               ("iiwa14", lambda d: d["end_effector"].update(actuators=[7]), "end_effector.actuators"),
                               ("compi", lambda d: d["end_effector"]["params"].update(lip_height=[0.04]), "end_effector.params.lip_height")):
        data = yaml.safe_load((MODELS_DIR / robot / "robot.yaml").read_text())
        data["model"]["file"] = str(MODELS_DIR / robot / data["model"]["file"])
        edit(data)
        path = tmp_path / f"{robot}.yaml"
        path.write_text(yaml.safe_dump(data))
        assert main(["simulate", "--robot", str(path), "--json"]) == 2
        err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("besdrake: error:")]
        assert len(err) == 1 and field in err[0] and "internal error" not in err[0], err


# ---------------------------------------------------------------------------------------- fuzzer


def test_fuzzer_fast_subset():
    """40 seeded mutations per format (360 cases, robot files included, in-process): no traceback, no modified input."""
    import importlib.util
    import sys

    spec = importlib.util.spec_from_file_location("bench_fuzz", Path(__file__).resolve().parents[1] / "scripts" / "bench_fuzz.py")
    fuzz = importlib.util.module_from_spec(spec)
    sys.modules["bench_fuzz"] = fuzz  # its dataclasses look their module up
    spec.loader.exec_module(fuzz)
    res = fuzz.fuzz(per_format=40, seed0=1000)
    assert res["total"]["cases"] == 40 * len(fuzz.FORMATS)
    assert res["total"]["tracebacks"] == 0, res["failures"][:3]
    assert res["total"]["modified_inputs"] == 0, res["failures"][:3]
    assert res["total"]["bad_error_lines"] == 0, res["failures"][:3]
    assert res["total"]["error"] > 0 and res["total"]["ok"] > 0  # the mutations reach both ends


def test_corrupt_optimizer_state_on_resume_says_how_to_recover(tmp_path):
    from besdrake.search.cmaes import CMAES
    from besdrake.search.loop import STATE_FILE, ResumeError, _restore

    (tmp_path / f"{STATE_FILE}.json").write_text('{"optimizer": {"mean": [1, 2')
    (tmp_path / f"{STATE_FILE}.npz").write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(ResumeError, match="damaged.*to recover, delete the folder"):
        _restore(CMAES(np.zeros(2), 1.0, np.random.default_rng(0)), tmp_path)


def test_copied_run_folder_uses_its_own_refined_scenario(tmp_path):
    from besdrake.pipeline.config import load_config
    from besdrake.pipeline.learn import Context
    from besdrake.tasks.throwing.learn.transfer import refined_scenario as _refined_scenario
    from besdrake.pipeline.run import RunFolder

    config = load_config(None, quick=True)
    run = RunFolder(tmp_path / "a", config)
    d = run.stage_dir(6, "diagnose")
    (d / "report").mkdir()
    (d / "report" / "refined_scenario.yaml").write_text("name: x\n")
    run.mark_done(6, "diagnose", {"refined_scenario": "06_diagnose/report/refined_scenario.yaml"}, 1.0)
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    shutil.rmtree(tmp_path / "a")
    copy = RunFolder(tmp_path / "b", config)
    got = Path(_refined_scenario(Context(copy, config)))
    assert got == tmp_path / "b" / "06_diagnose" / "report" / "refined_scenario.yaml" and got.is_file()


@pytest.mark.parametrize("setting", ["transfer.population=-3", "transfer.max_transfers=0", "transfer.final_repetitions=0"])
def test_learn_refuses_a_transfer_count_below_its_least_before_running(tmp_path, capsys, setting):
    err = _error(capsys, ["learn", "--quick", "--set", setting, "--out", str(tmp_path / "run")])
    assert err.startswith("besdrake: error: transfer:") and "whole number" in err
    assert not (tmp_path / "run").exists()  # refused before any stage ran
