"""The diagnosis on pick-and-place lab logs (issue 25, item 6): the task's hidden lab effects are registry effects
that its rollout applies and its lab hides its truth with; the default candidates are the scenario's task's; the
task's trial model reads a lab measurement and a simulated outcome alike; and ``diagnose`` on a lab log with a hidden
box pose offset names it and lowers the held-out disparity (slow)."""

from __future__ import annotations

import numpy as np
import pytest

from besdrake.diagnosis import DiagnosisError, diagnose
from besdrake.sim.effects import EffectError, get_effect
from besdrake.task import effects_for
from besdrake.tasks.pick_and_place.diagnosis.model import MODEL
from besdrake.tasks.pick_and_place.lab import PickPlaceLab

QUIET = {"placement_sd": 0.0, "placement_yaw_sd": 0.0, "pose_noise_sd": 0.0, "angle_noise_sd": 0.0, "encoder_noise_sd": 0.0}
THROWING = ["base_offset", "joint_offset", "actuator_lag", "gain_scale", "air_drag", "ball_placement", "ball", "scoop_friction", "scoop_mount"]


def lab_with(effects: dict, noise: dict | None = None, rollout=None, seed: int = 0) -> PickPlaceLab:
    return PickPlaceLab({"name": "test_pnp_diag", "scenario": "pick_and_place", "seed": seed, "effects": effects,
                         "noise": QUIET if noise is None else noise}, rollout=rollout)


@pytest.fixture(scope="module")
def quiet() -> PickPlaceLab:
    return lab_with({})


@pytest.fixture(scope="module")
def plan(quiet):
    from besdrake.tasks.pick_and_place.diagnosis.design import pick_plan

    return pick_plan(quiet.rollout)


def test_each_task_gets_its_own_candidates_and_refuses_another_tasks():
    assert effects_for("throwing") == THROWING  # throwing's default candidates did not grow
    assert effects_for("pick_and_place") == ["joint_offset", "actuator_lag", "box_pose_offset", "box_mass", "pad_friction"]
    for name in ("box_pose_offset", "box_mass", "pad_friction"):
        assert len(get_effect(name).describe()["doc"]) > 80, f"{name} needs a physics docstring"
    with pytest.raises(DiagnosisError, match="do not act on throwing"):
        diagnose([], candidates=["base_offset", "box_mass"])
    with pytest.raises(DiagnosisError, match="do not act on pick_and_place"):
        diagnose([], scenario="pick_and_place", candidates=["air_drag"])


def test_the_rollout_refuses_an_effect_only_another_task_lists(quiet, plan):
    with pytest.raises(EffectError, match="base_offset"):
        quiet.rollout.rollout(plan, effects={"base_offset": {"z": 0.01}})


def test_the_lab_hides_its_truth_with_the_registry_effects_and_the_model_reads_both_alike(quiet, plan):
    lab = lab_with({"box_pose_offset": {"x": 0.015}, "box_mass": 0.3, "pad_friction": 0.4, "joint_offset": {"joint2": 0.01}},
                   rollout=quiet.rollout)
    r = quiet.rollout
    hidden = lab.hidden_effects()
    assert hidden["box_pose_offset"] == {"x": 0.015, "y": 0.0, "yaw": 0.0}
    assert hidden["box_mass"]["delta"] == pytest.approx(0.3 - r.box_mass)
    assert hidden["pad_friction"]["scale"] == pytest.approx(0.4 / r.pad_friction)
    m = lab.execute(plan, trial=0)
    sim = r.rollout(plan, effects=hidden)  # the same effects in the simulation: the same trial
    nominal = r.rollout(plan)
    layout = MODEL.make_layout(m, nominal)
    measured, _ = MODEL.measured_features(m, layout)
    simulated = MODEL.simulated_features(sim, layout)
    sl = MODEL.slices()
    assert measured.shape == (MODEL.n_features,) and np.all(np.isfinite(measured))
    np.testing.assert_allclose(measured[sl["box"]], simulated[sl["box"]], atol=1e-6)
    np.testing.assert_allclose(measured[sl["joints"]], simulated[sl["joints"]], atol=1e-6)  # encoders read true - offset
    assert abs(measured[sl["grip"]][0] - simulated[sl["grip"]][0]) < 1e-3  # lift: from the shelf vs the box's first sample
    # the hidden truth moves the box where the nominal simulation does not put it
    assert np.linalg.norm(measured[sl["box"]] - MODEL.simulated_features(nominal, layout)[sl["box"]]) > 0.005


def test_designed_picks_spread_places_and_speeds_and_repeat_some(quiet):
    from besdrake.tasks.pick_and_place.diagnosis.design import diagnosis_plans

    plans = diagnosis_plans(6, 2, seed=1, limits=quiet.robot.limits, rollout=quiet.rollout)
    names = [p.meta["name"] for p in plans]
    assert len(plans) == 6 and len(set(names)) == 4
    assert all(p.check_limits(quiet.robot.limits).ok for p in plans)
    distinct = {p.meta["name"]: p for p in plans}.values()
    assert len({round(p.meta["place_dx"], 4) for p in distinct}) == 4 and len({round(p.duration, 2) for p in distinct}) >= 3


@pytest.mark.slow
def test_a_hidden_box_pose_offset_is_named_and_the_heldout_disparity_drops(quiet):
    """About 100 rollouts (2-4 min on a busy core)."""
    from besdrake.sim.scenario import load_scenario
    from besdrake.tasks.pick_and_place.diagnosis.design import diagnosis_plans

    lab = lab_with({"box_pose_offset": {"x": 0.015}}, noise={}, rollout=quiet.rollout, seed=3)
    plans = diagnosis_plans(8, 3, seed=1, limits=lab.robot.limits, rollout=quiet.rollout)
    log = [lab.execute(p, trial=i) for i, p in enumerate(plans)]
    d = diagnose(log, scenario=load_scenario("pick_and_place"), candidates=["box_pose_offset", "box_mass", "pad_friction"],
                 pairs=False, structural=False, backend="serial", folds=3)
    assert d.explained and list(d.best.effects) == ["box_pose_offset"], d.verdict
    x = d.best.to_dict()["parameters"]["box_pose_offset.x"]["value"]
    assert abs(x - 0.015) < 0.003, x
    g = d.gain
    assert g.median_disparity_before_m > 0.008 and g.median_disparity_after_m < 0.5 * g.median_disparity_before_m, g
