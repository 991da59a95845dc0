"""Free flight after release: closed form without drag, ODE with drag."""

from __future__ import annotations

import numpy as np
import pytest

from besdrake.tasks.throwing.flight import GRAVITY, fly


def test_parabola_lands_where_kinematics_says():
    p0, v0, r = np.array([0.1, 0.0, 1.5]), np.array([3.0, 0.5, 1.0]), 0.035
    f = fly(p0, v0, r)
    T = (1.0 + np.sqrt(1.0 + 2 * GRAVITY * (1.5 - r))) / GRAVITY
    assert f.duration == pytest.approx(T)
    assert np.allclose(f.touchdown_position, [0.1 + 3 * T, 0.5 * T, r])
    assert f.path.shape == (60, 3) and np.allclose(f.path[0], p0)


def test_tiny_drag_matches_the_parabola_and_drag_shortens():
    p0, v0 = np.array([0.0, 0.0, 1.6]), np.array([3.0, 0.0, 1.5])
    vac = fly(p0, v0, 0.035)
    tiny = fly(p0, v0, 0.035, drag_coefficient=1e-9)
    assert np.allclose(tiny.touchdown_position, vac.touchdown_position, atol=1e-6)
    drag = fly(p0, v0, 0.035, mass=0.05, drag_coefficient=0.5)
    assert drag.touchdown_position[0] < vac.touchdown_position[0] - 0.02
    assert drag.touchdown_position[2] == pytest.approx(0.035)
    heavier = fly(p0, v0, 0.035, mass=0.2, drag_coefficient=0.5)
    assert drag.touchdown_position[0] < heavier.touchdown_position[0] < vac.touchdown_position[0]


def test_ball_already_on_the_floor():
    f = fly(np.array([1.0, 0.0, 0.03]), np.array([1.0, 0.0, 0.0]), 0.035)
    assert f.duration == 0.0 and np.allclose(f.touchdown_position, [1.0, 0.0, 0.03])
