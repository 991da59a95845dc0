"""The per-throw observables: the ball at rest in the scoop before the throw shows where the arm and ball are."""

from __future__ import annotations

import numpy as np

from besdrake.tasks.throwing.diagnosis import observables
from besdrake.sim import Rollout
from besdrake.tasks.throwing.throws import default_throw
from besdrake.tasks.throwing.lab import VirtualLab

QUIET = {"touchdown_sd": 0.0, "mocap_noise_sd": 0.0, "encoder_noise_sd": 0.0, "ball_placement_sd": 0.0}


def _rest(effects: dict, record_ball_path: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The ball_rest features of one default throw: measured in a quiet virtual lab with ``effects``, and simulated
    nominally at the same sample times."""
    plan = default_throw(0.35)
    lab = VirtualLab({"name": "quiet", "effects": effects, "seed": 0, "noise": QUIET, "record_ball_path": record_ball_path})
    m = lab.execute(plan)
    nominal = Rollout("nominal").rollout(plan, limits="flag")
    lay = observables.make_layout(m, nominal)
    s = observables.group_slices()["ball_rest"]
    return observables.measured_features(m, lay)[0][s], observables.simulated_features(nominal, lay)[s]


def test_the_ball_at_rest_is_read_alike_from_the_lab_and_the_simulation():
    meas, sim = _rest({})
    assert np.all(np.isfinite(meas)) and np.abs(meas - sim).max() < 2e-4
    assert meas[2] > 1.0  # in the scoop, above the floor


def test_the_ball_at_rest_shows_a_base_offset_and_a_placement_habit():
    base, sim = _rest({"base_offset": {"z": -0.03}})
    np.testing.assert_allclose(base - sim, [0.0, 0.0, -0.03], atol=1e-3)
    habit, sim = _rest({"ball_placement": {"y": 0.003}})
    d = habit - sim
    # 3 mm off centre in the scoop: about 3 mm sideways, and the funnel lifts the ball.
    assert 0.002 < np.hypot(d[0], d[1]) < 0.004 and d[2] > 0.001, d


def test_a_log_without_the_ball_path_has_no_rest_position():
    meas, _ = _rest({}, record_ball_path=False)
    assert np.all(np.isnan(meas))


def test_marker_noise_of_the_rest_position_shrinks_with_its_samples():
    t = np.linspace(0.5, 0.8, 40)
    sd = observables.ball_fit_sd([t, t], [0.65, 0.65], 0.001, [np.arange(7) * 0.005, np.arange(7) * 0.005])
    assert abs(sd["ball_rest"] - 0.001 / np.sqrt(7)) < 1e-12
    assert sd["ball_pos"] > 0 and "ball_rest" not in observables.ball_fit_sd([t], [0.65], 0.001)
