"""Pick-and-place simulation (issue 24): the iiwa 14 model and robot file, the scene, the rollout's outcome flags."""

from __future__ import annotations

import copy
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from besdrake.plan import MotionPlan, PlanError
from besdrake.robot import MODELS_DIR, load_robot

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def _module(path: Path):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def rollout():
    from besdrake.tasks.pick_and_place.rollout import PickPlaceRollout

    return PickPlaceRollout()


@pytest.fixture(scope="module")
def plan(rollout):
    from besdrake.tasks.pick_and_place.scripted import scripted_plan_for

    return scripted_plan_for(rollout)


@pytest.fixture(scope="module")
def nominal(rollout, plan):
    return rollout.rollout(plan)


def test_iiwa_robot_file_has_the_data_sheet_limits():
    robot = load_robot("iiwa14")
    assert robot.n_joints == 7 and robot.end_effector.type == "gripper"
    np.testing.assert_allclose(np.degrees(robot.position_limits[:, 1]), [170, 120, 170, 120, 170, 120, 175])
    np.testing.assert_allclose(np.degrees(robot.velocity_limits), [85, 85, 100, 75, 130, 135, 135])
    np.testing.assert_allclose(robot.effort, [320, 320, 176, 176, 110, 40, 40])
    assert robot.end_effector.gripper.coupled == ("right_finger_joint",)
    assert {"kinematics", "position", "velocity", "effort", "acceleration", "masses", "gripper"} <= set(robot.sources)


def test_generated_models_match_the_committed_files(tmp_path):
    gen = _module(MODELS_DIR / "iiwa14" / "generate_urdf.py")
    assert gen.main(tmp_path / "iiwa14.urdf").read_text() == (MODELS_DIR / "iiwa14" / "iiwa14.urdf").read_text()
    make = _module(MODELS_DIR / "pick_and_place" / "make_models.py")
    for p in make.main(tmp_path):
        assert p.read_text() == (MODELS_DIR / "pick_and_place" / p.name).read_text(), p.name


def test_iiwa_kinematics_and_mass():
    from pydrake.multibody.plant import MultibodyPlant

    robot = load_robot("iiwa14")
    plant = MultibodyPlant(0.0)
    instance = robot.add_model(plant)
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName(robot.base_link, instance))
    plant.Finalize()
    ctx = plant.CreateDefaultContext()
    flange = plant.GetFrameByName("gripper_base", instance).CalcPoseInWorld(ctx).translation()
    np.testing.assert_allclose(flange, [0, 0, 0.36 + 0.42 + 0.40 + 0.126], atol=1e-9)  # data sheet, arm straight up
    arm = sum(plant.GetBodyByName(f"iiwa_link_{i}", instance).default_mass() for i in range(1, 8))
    assert arm == pytest.approx(6.404 + 7.89 + 2.54 + 4.82 + 1.76 + 2.50 + 0.42)


def test_scripted_pick_and_place_succeeds(nominal, rollout):
    out = nominal
    assert out.success, out.message
    assert out.grasped and out.lifted and out.held and out.upright and out.on_table and out.limits_kept
    assert not any(out.flags.values())
    assert out.place_error < 0.03 and out.max_slip < 0.01
    assert abs(out.box_position[2] - rollout.place_target[2]) < 0.005
    assert out.reward > -0.03
    json.dumps(out.to_dict())


def test_slippery_box_slips_out_of_the_grasp(rollout, plan, nominal):
    # 20 N per pad: the box (0.2 kg) needs a combined friction above 0.049; box 0.02 with the pads' 1.0 gives 0.039
    out = rollout.rollout(plan, box_friction=0.02, box_mass=0.25)
    assert not out.success and out.grasped
    assert out.flags["slipped"] and out.flags["not_lifted"]
    again = rollout.rollout(plan)  # the Context is reset: the box's friction and mass are the model's again
    assert again.success and again.place_error == pytest.approx(nominal.place_error, abs=1e-9)


def test_unclosed_gripper_does_not_lift(rollout, plan):
    meta = copy.deepcopy(plan.meta)
    meta["gripper"] = {"t": [0.0], "width": [0.11]}
    out = rollout.rollout(MotionPlan(plan.t, plan.q, plan.qd, meta, plan.joint_names))
    assert not out.success and not out.grasped
    assert out.flags["not_lifted"] and not out.flags["slipped"]


def test_plan_through_the_shelf_is_flagged(rollout):
    from besdrake.sim.diagram import base_transform
    from besdrake.tasks.pick_and_place.scripted import ToolIK, _tool_rotation

    robot = rollout.robot
    ik = ToolIK(robot, base_transform(rollout.scenario))
    inside = ik.solve(np.array([0.85, 0.0, 1.215]), _tool_rotation(np.array([1.0, 0.0, 0.0])), robot.home)  # in the board
    plan = MotionPlan(t=[0.0, 2.0, 2.5], q=[robot.home, inside, inside], qd=np.zeros((3, 7)), joint_names=robot.joint_names)
    out = rollout.rollout(plan)
    assert out.flags["arm_fixture_collision"] and "shelf" in out.collision
    assert not out.success


def test_plan_beyond_the_limits_is_flagged_not_raised(rollout, plan):
    fast = MotionPlan(plan.t * 0.5, plan.q, plan.qd, plan.meta, plan.joint_names)
    out = rollout.rollout(fast)
    assert out.flags["joint_limit_exceeded"] and not out.success


def test_malformed_gripper_command_is_refused(rollout, plan):
    meta = dict(plan.meta, gripper={"t": [0.0, 1.0], "width": [0.1]})
    with pytest.raises(PlanError, match="gripper"):
        rollout.rollout(MotionPlan(plan.t, plan.q, plan.qd, meta, plan.joint_names))


@pytest.mark.parametrize("field, value", [("coupled_joints", ["no_such_finger"]), ("actuators", ["no_such_motor"])])
def test_robot_file_refuses_an_unknown_gripper_name(tmp_path, field, value):
    import yaml

    from besdrake.robot import RobotError

    src = MODELS_DIR / "iiwa14" / "robot.yaml"
    data = yaml.safe_load(src.read_text())
    data["model"]["file"] = str(MODELS_DIR / "iiwa14" / "iiwa14.urdf")
    data["end_effector"][field] = value
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(RobotError, match=rf"bad.yaml: end_effector.{field}\[0\]"):
        load_robot(bad)


@pytest.fixture(scope="module")
def panda_rollout():
    """The same scene with the Panda (only the robot file differs); skipped without ``besdrake[robots]``."""
    from besdrake.robot import RobotError
    from besdrake.sim.scenario import load_scenario
    from besdrake.tasks.pick_and_place.rollout import PickPlaceRollout

    try:
        load_robot("panda")
    except RobotError as err:
        pytest.skip(f"the Panda needs example-robot-data (pip install 'besdrake[robots]'): {err}")
    return PickPlaceRollout(load_scenario("pick_and_place").with_robot("panda"))


def test_panda_runs_the_same_scripted_pick_and_place(panda_rollout):
    from besdrake.tasks.pick_and_place.scripted import scripted_plan_for

    robot = panda_rollout.robot
    assert robot.name == "panda" and robot.end_effector.gripper.coupled == ("panda_finger_joint2",)
    plan = scripted_plan_for(panda_rollout)
    out = panda_rollout.rollout(plan)
    assert out.success, out.message
    assert out.place_error < 0.03 and out.held and out.upright
    slippery = panda_rollout.rollout(plan, box_friction=0.02)
    assert slippery.flags["slipped"] and not slippery.success


def test_solver_failure_is_a_flagged_outcome(plan):
    from besdrake.tasks.pick_and_place.rollout import PickPlaceRollout

    class FailingSimulator:
        """The real simulator, whose solver fails once it has to advance."""

        def __init__(self, sim):
            self.sim = sim

        def Initialize(self):
            return self.sim.Initialize()

        def AdvanceTo(self, t):
            raise RuntimeError("SAP solver failed to converge")

    broken = PickPlaceRollout()
    broken.simulator = FailingSimulator(broken.simulator)
    out = broken.rollout(plan)
    assert out.flags["sim_failed"] and not out.success
    assert "SAP solver failed" in out.message and np.isfinite(out.reward)


@pytest.mark.parametrize("robot", ["iiwa14", "panda"])
def test_simulate_runs_the_tasks_default_plan_on_either_arm(robot, capsys):
    """``besdrake simulate --scenario pick_and_place --robot NAME``: the same task on two arms, only the robot
    file differing (the scripted plan's inverse kinematics is solved for each arm)."""
    import json

    from besdrake.cli import main

    from besdrake.robot import RobotError

    try:
        load_robot(robot)
    except RobotError as err:
        pytest.skip(f"the Panda needs example-robot-data (pip install 'besdrake[robots]'): {err}")
    assert main(["simulate", "--scenario", "pick_and_place", "--robot", robot, "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["success"] and summary["place_error_m"] < 0.03 and not summary["arm_fixture_collision"]
    assert main(["simulate", "--scenario", "pick_and_place", "--amplitude", "0.3"]) == 2
    assert "takes --plan FILE" in capsys.readouterr().err
