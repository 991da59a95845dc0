"""The throwing scoop's geometry, read from COMPI's robot file."""

from __future__ import annotations

import numpy as np
import pytest

from besdrake.robot import load_robot
from besdrake.tasks.throwing.scoop import Scoop

SCOOP = Scoop.of(load_robot("compi"))


def test_ball_rest_height_touches_the_walls():
    r = 0.035
    c = SCOOP.rest_height(r)
    a, al = SCOOP.bottom_half_width, SCOOP.wall_angle
    # distance from the centre (0, 0, c) to the wall plane through (a, 0, 0) with inward normal (-sin, 0, cos)
    assert a * np.sin(al) + c * np.cos(al) == pytest.approx(r)
    assert SCOOP.lip_height > c  # the lip rises above the ball's centre


def test_distance_to_scoop_surfaces():
    r = 0.035
    assert SCOOP.distance([0.0, 0.0, SCOOP.rest_height(r)]) == pytest.approx(r)
    # straight above the funnel: the nearest surface is the rim, at the top of the walls
    d = SCOOP.distance([0.0, 0.0, 0.5])
    assert d == pytest.approx(np.hypot(SCOOP.top_half_width, 0.5 - SCOOP.lip_height), rel=1e-6)
    assert SCOOP.distance([0.0, 0.0, SCOOP.floor_z - 0.1]) == pytest.approx(0.1)  # below the floor plate
    many = SCOOP.distance(np.array([[0.0, 0.0, 0.5], [0.0, 0.0, SCOOP.floor_z - 0.1]]))
    assert many.shape == (2,) and many[1] == pytest.approx(0.1)


def test_one_point_distance_is_the_array_formula():
    """The plain-float path for one point (the rollout's per-chunk check) gives the array path's distances."""
    pts = np.random.default_rng(0).uniform(-0.1, 0.1, (500, 3))
    one = np.array([SCOOP.distance(p) for p in pts])
    assert isinstance(SCOOP.distance(pts[0]), float)
    assert np.allclose(one, SCOOP.distance(pts), rtol=0.0, atol=1e-15)


def test_a_robot_without_scoop_geometry_is_refused(tmp_path):
    import dataclasses

    from besdrake.robot import RobotError

    robot = load_robot("compi")
    bare = dataclasses.replace(robot, end_effector=dataclasses.replace(robot.end_effector, params={}))
    with pytest.raises(RobotError, match="a scoop needs"):
        Scoop.of(bare)
