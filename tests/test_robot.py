"""Robots as data: the robot file is read and checked against its model; COMPI's file matches its URDF."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from besdrake.robot import MODELS_DIR, Robot, RobotError, known_robots, load_robot, robot_file

COMPI_YAML = MODELS_DIR / "compi" / "robot.yaml"


def _plant(robot: Robot):
    from pydrake.multibody.plant import MultibodyPlant

    plant = MultibodyPlant(0.0)
    robot.add_model(plant)
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName(robot.base_link))
    plant.Finalize()
    return plant


def test_compi_is_built_in_and_found_by_name_or_path():
    assert "compi" in known_robots()
    by_name, by_path = load_robot("compi"), load_robot(COMPI_YAML)
    assert by_name is by_path  # one cached object per file
    assert by_name.reference == "compi"
    assert by_name.joint_names == tuple(f"joint{k}" for k in range(1, 7))
    assert by_name.position_limits.shape == (6, 2) and by_name.position_limits[1].tolist() == [-1.8, 2.09]
    assert np.allclose(by_name.velocity_limits, 3.14) and np.allclose(by_name.acceleration_limits, 20.0)
    assert by_name.end_effector.type == "fixed" and by_name.end_effector.gripper is None
    with pytest.raises(ValueError):
        by_name.position_limits[0, 0] = 0.0  # read-only


def test_compi_file_agrees_with_its_urdf():
    robot = load_robot("compi")
    plant = _plant(robot)
    for name, (lo, hi), v in zip(robot.joint_names, robot.position_limits, robot.velocity_limits):
        joint = plant.GetJointByName(name)
        assert joint.position_lower_limits()[0] == pytest.approx(lo)
        assert joint.position_upper_limits()[0] == pytest.approx(hi)
        assert joint.velocity_upper_limits()[0] == pytest.approx(v)
    ctx = plant.CreateDefaultContext()
    tool = plant.CalcRelativeTransform(ctx, plant.world_frame(), plant.GetFrameByName(robot.tool_frame)).translation()
    assert np.allclose(tool, [0.0, 0.0, 1.174], atol=1e-9)  # arm straight up: the published link lengths
    plant.SetPositions(ctx, [0.0, 0.3, 0.0, 0.0, 0.0, 0.0])
    p = plant.CalcRelativeTransform(ctx, plant.world_frame(), plant.GetFrameByName(robot.tool_frame)).translation()
    assert p[0] > 0.2 and abs(p[1]) < 1e-9  # positive joint2 tilts the arm forward along x


def _write(tmp_path: Path, mutate) -> Path:
    data = yaml.safe_load(COMPI_YAML.read_text())
    data["model"]["file"] = str(COMPI_YAML.parent / "compi.urdf")
    mutate(data)
    path = tmp_path / "my_arm.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(
    "mutate, field",
    [
        (lambda d: d["joints"][2].update(name="elbow"), r"joints\[2\]\.name: the model has no joint 'elbow'"),
        (lambda d: d["joints"][1].update(position=[1.2, 0.5]), r"joints\[1\]\.position: lower limit 1\.2 is not below"),
        (lambda d: d["joints"][0].update(velocity=-1), r"joints\[0\]\.velocity: must be > 0"),
        (lambda d: d.update(tool_frame="flange"), r"tool_frame: the model has no frame 'flange'"),
        (lambda d: d["model"].update(file="nowhere.urdf"), r"model\.file: model file not found"),
        (lambda d: d.pop("base_link"), r"base_link: missing"),
        (lambda d: d.update(home=[0, 0, 0, 0, 5.0, 0]), r"home: pose .* is outside the joint limits"),
        (lambda d: d.update(colour="red"), r"colour: unknown field"),
        (lambda d: d["end_effector"].update(body="hand"), r"end_effector\.body: the model has no body 'hand'"),
        (lambda d: d["joints"][3].update(actuator="nope_motor"), r"joints\[3\]\.actuator: the model has no actuator"),
    ],
)
def test_a_bad_robot_file_names_the_file_and_the_field(tmp_path, mutate, field):
    path = _write(tmp_path, mutate)
    with pytest.raises(RobotError, match=field) as info:
        load_robot(path)
    assert str(path) in str(info.value)


def test_unknown_names_and_files_are_refused():
    with pytest.raises(RobotError, match="unknown robot 'r2d2'.*built-in robots"):
        load_robot("r2d2")
    with pytest.raises(RobotError, match="robot file not found"):
        robot_file("no/such/robot.yaml")


def test_a_robot_added_by_a_yaml_file_alone_simulates_and_is_gated(tmp_path):
    """A third party's file (here COMPI's model with slower drives, in a folder of its own) runs
    ``besdrake simulate`` and the safety gate, with no code."""
    from besdrake.tasks.throwing.throws import default_throw
    from besdrake.transfer.lab import SafetyGate
    from besdrake.transfer.measurement import Measurement

    path = _write(tmp_path, lambda d: [j.update(velocity=1.0) for j in d["joints"]] and d.update(name="slow_arm"))
    robot = load_robot(path)
    assert robot.name == "slow_arm" and np.allclose(robot.velocity_limits, 1.0)
    out = subprocess.run([sys.executable, "-m", "besdrake", "simulate", "--robot", str(path), "--json", "--limits", "flag"],
                         capture_output=True, text=True, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    summary = json.loads(out.stdout.strip().splitlines()[-1])
    assert summary["touchdown_m"] is not None and summary["flags"] == ["joint_limit_exceeded"]  # its own, slower limits

    class Spy:
        robot = load_robot(path)
        calls = 0

        def execute(self, plan, trial=None):
            Spy.calls += 1
            return Measurement(trial=trial or 0, plan=plan)

    m = SafetyGate(Spy()).execute(default_throw(0.35))  # ~2 rad/s: beyond the slow arm's 1 rad/s
    assert m.flags.get("refused_by_safety_gate") and "velocity" in m.message and Spy.calls == 0
    bad = subprocess.run([sys.executable, "-m", "besdrake", "simulate", "--robot", str(tmp_path / "missing.yaml")],
                         capture_output=True, text=True, cwd=tmp_path)
    assert bad.returncode == 2 and bad.stderr.startswith("besdrake: error:") and "Traceback" not in bad.stderr
