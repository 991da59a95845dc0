"""COMPI facts in besdrake.robot agree with the model file and the published kinematics."""

from __future__ import annotations

import numpy as np
import pytest

from besdrake import robot


def _plant():
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import MultibodyPlant

    plant = MultibodyPlant(0.0)
    parser = Parser(plant)
    robot.add_package(parser.package_map())
    parser.AddModels(url=f"package://{robot.PACKAGE_NAME}/compi/compi.urdf")
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName(robot.BASE_LINK))
    plant.Finalize()
    return plant


def test_constants_shapes_and_values():
    assert len(robot.JOINT_NAMES) == 6
    assert robot.POSITION_LIMITS.shape == (6, 2)
    assert np.all(robot.POSITION_LIMITS[:, 0] < robot.POSITION_LIMITS[:, 1])
    assert robot.POSITION_LIMITS[1].tolist() == [-1.8, 2.09]
    assert np.allclose(robot.VELOCITY_LIMITS, 3.14)
    assert robot.ACCELERATION_LIMITS.shape == (6,) and np.all(robot.ACCELERATION_LIMITS > 0)
    with pytest.raises(ValueError):
        robot.POSITION_LIMITS[0, 0] = 0.0  # read-only


def test_package_url_resolves_and_limits_match_urdf():
    plant = _plant()
    for name, (lo, hi) in zip(robot.JOINT_NAMES, robot.POSITION_LIMITS):
        joint = plant.GetJointByName(name)
        assert joint.position_lower_limits()[0] == pytest.approx(lo)
        assert joint.position_upper_limits()[0] == pytest.approx(hi)
        assert joint.velocity_upper_limits()[0] == pytest.approx(3.14)


def test_tcp_at_zero_configuration_is_1174_mm_up():
    plant = _plant()
    ctx = plant.CreateDefaultContext()
    p = plant.CalcRelativeTransform(ctx, plant.world_frame(), plant.GetFrameByName(robot.TCP_FRAME)).translation()
    assert np.allclose(p, [0.0, 0.0, 1.174], atol=1e-9)
    assert robot.TCP_HEIGHT_AT_ZERO == pytest.approx(1.174)


def test_positive_joint2_tilts_arm_forward_along_x():
    plant = _plant()
    ctx = plant.CreateDefaultContext()
    plant.SetPositions(ctx, [0.0, 0.3, 0.0, 0.0, 0.0, 0.0])
    p = plant.CalcRelativeTransform(ctx, plant.world_frame(), plant.GetFrameByName(robot.TCP_FRAME)).translation()
    assert p[0] > 0.2 and abs(p[1]) < 1e-9


def test_ball_rest_height_touches_the_walls():
    r = 0.035
    c = robot.ball_rest_height(r)
    a, al = robot.SCOOP_BOTTOM_HALF_WIDTH, robot.SCOOP_WALL_ANGLE
    # distance from the centre (0, 0, c) to the wall plane through (a, 0, 0) with inward normal (-sin, 0, cos)
    assert a * np.sin(al) + c * np.cos(al) == pytest.approx(r)
    assert robot.SCOOP_LIP_HEIGHT > c  # the lip rises above the ball's centre


def test_missing_model_file_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setattr(robot, "MODELS_DIR", tmp_path)
    with pytest.raises(FileNotFoundError, match="COMPI model file missing"):
        robot.compi_model_path()
    with pytest.raises(FileNotFoundError, match="package file missing"):
        robot.package_xml_path()


def test_distance_to_scoop_surfaces():
    r = 0.035
    assert robot.distance_to_scoop([0.0, 0.0, robot.ball_rest_height(r)]) == pytest.approx(r)
    # straight above the funnel: the nearest surface is the rim, at the top of the walls
    top = robot.SCOOP_TOP_HALF_WIDTH
    d = robot.distance_to_scoop([0.0, 0.0, 0.5])
    assert d == pytest.approx(np.hypot(top, 0.5 - robot.SCOOP_LIP_HEIGHT), rel=1e-6)
    # below the floor plate
    assert robot.distance_to_scoop([0.0, 0.0, robot.SCOOP_FLOOR_Z - 0.1]) == pytest.approx(0.1)
