"""Scenario files: the nominal one loads, bad ones give ScenarioError naming the problem."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from besdrake.sim.scenario import DIAGRAMS_DIR, ScenarioError, load_scenario, scenario_from_dict


def _nominal_dict():
    return yaml.safe_load((DIAGRAMS_DIR / "nominal.yaml").read_text())


def test_nominal_loads_by_name_and_path():
    s = load_scenario("nominal")
    assert s.name == "nominal" and s.time_step == pytest.approx(0.0025)
    assert s.contact_approximation in ("sap", "lagged", "similar")
    assert len(s.controller.kp) == 6 and s.base.z > 0
    assert load_scenario(DIAGRAMS_DIR / "nominal.yaml").to_dict() == s.to_dict()
    assert load_scenario("reference_1ms").time_step == pytest.approx(0.001)


def test_with_overrides_copies():
    s = load_scenario("nominal")
    r = s.with_overrides(time_step=0.001)
    assert r.time_step == 0.001 and s.time_step == 0.0025
    with pytest.raises(ScenarioError, match="no field"):
        s.with_overrides(bogus=1)


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda d: d.pop("time_step"), "time_step"),
        (lambda d: d.update(time_step=0.5), r"time_step=0.5 is outside"),
        (lambda d: d.update(time_step="fast"), "must be a number"),
        (lambda d: d["contact"].update(approximation="tamsi"), "TAMSI ignores"),
        (lambda d: d.update(colour="red"), "unknown key"),
        (lambda d: d["models"].update(ball="package://besdrake_models/ball/nope.sdf"), "model file for 'ball' not found"),
        (lambda d: d["models"].update(ball="package://other/x.sdf"), "unknown package"),
        (lambda d: d.pop("robot"), "missing 'robot'"),
        (lambda d: d.update(robot="r2d2"), "unknown robot 'r2d2'"),
        (lambda d: d.pop("task"), "missing 'task'"),
        (lambda d: d.update(task="juggling"), "unknown task 'juggling'"),
        (lambda d: d.update(controller={"kp": [1, 2, 3]}), "list of 6"),
        (lambda d: d.update(controller={"kd": [1, 2, 3, 4, 5, float("nan")]}), "finite"),
        (lambda d: d["base"].update(z=-1), "base.z"),
        (lambda d: d.update(effects={"warp_drive": {}}), "unknown effect 'warp_drive'"),
        (lambda d: d.update(effects={"base_offset": {"z": 5.0}}), "outside its bounds"),
        (lambda d: d.update(release="soon"), "must be a mapping"),
    ],
)
def test_invalid_scenarios_name_the_problem(mutate, match):
    d = _nominal_dict()
    mutate(d)
    with pytest.raises(ScenarioError, match=match):
        scenario_from_dict(d)


def test_file_level_errors(tmp_path: Path):
    with pytest.raises(ScenarioError, match="not found.*known scenarios"):
        load_scenario("no_such_scenario")
    bad = tmp_path / "bad.yaml"
    bad.write_text("time_step: [1, 2\n")
    with pytest.raises(ScenarioError, match="not valid YAML"):
        load_scenario(bad)
    lst = tmp_path / "list.yaml"
    lst.write_text("- 1\n- 2\n")
    with pytest.raises(ScenarioError, match="mapping"):
        load_scenario(lst)


def test_scenario_effects_are_completed_with_nominals():
    d = _nominal_dict()
    d["effects"] = {"air_drag": {"cd": 0.5}}
    s = scenario_from_dict(d)
    assert s.effects == {"air_drag": {"cd": 0.5, "rho": 1.2}}


def test_the_throwing_diagram_needs_its_ball_and_floor():
    from besdrake.sim.diagram import build_diagram

    d = _nominal_dict()
    d["models"].pop("ball")
    with pytest.raises(ScenarioError, match="missing 'ball'"):
        build_diagram(scenario_from_dict(d))


def test_a_scenario_moves_to_another_robot_with_its_gains():
    s = load_scenario("nominal")
    assert s.robot.name == "compi" and s.to_dict()["robot"] == "compi"
    assert s.controller.kp == [2000, 4000, 3000, 800, 800, 200]  # the robot file's gains where the scenario gives none
    moved = s.with_robot("compi")
    assert moved.robot is s.robot and moved.controller.kp == s.controller.kp
    with pytest.raises(ScenarioError, match="unknown robot"):
        s.with_robot("r2d2")


def test_tasks_are_plug_ins_found_by_name(tmp_path):
    from besdrake.task import Task, TaskError, get_task, known_tasks, register_task

    assert "throwing" in known_tasks() and get_task("throwing").name == "throwing"
    with pytest.raises(TaskError, match="unknown task 'juggling'"):
        get_task("juggling")

    @register_task
    class Juggling(Task):
        name = "juggling_test"
        default_scenario = "nominal"

        def make_rollout(self, scenario, meshcat=None):
            return None

        def failed_outcome(self, message):
            return {"failed": message}

    assert get_task("juggling_test").failed_outcome("x") == {"failed": "x"}
    d = _nominal_dict() | {"task": "juggling_test"}
    assert scenario_from_dict(d).task == "juggling_test"
    with pytest.raises(TaskError):
        register_task(int)
