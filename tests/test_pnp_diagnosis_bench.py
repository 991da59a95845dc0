"""scripts/bench_pnp_diagnosis.py: its truths and the check of each named value against the lab's hidden one (no
simulation)."""

from __future__ import annotations

from types import SimpleNamespace


def _param(effect, name, value, stderr, nominal=0.0):
    return {"effect": effect, "parameter": name, "value": value, "stderr": stderr, "nominal": nominal}


def test_a_named_value_is_checked_against_the_hidden_one_or_its_nominal(script):
    bench = script("bench_pnp_diagnosis")
    hidden = {"box_pose_offset": {"x": 0.012, "y": -0.008, "yaw": 0.05}, "box_mass": {"delta": 0.05}}
    cause = SimpleNamespace(parameters=[_param("box_pose_offset", "x", 0.01206, 0.0005), _param("box_pose_offset", "yaw", -0.0368, 0.0044),
                                        _param("box_mass", "delta", 0.0477, 0.0065), _param("pad_friction", "scale", 1.2, 0.05, nominal=1.0)])
    rows = {r["parameter"]: r for r in bench.parameters_vs_hidden(cause, hidden)}
    assert rows["box_pose_offset.x"]["consistent"] and rows["box_mass.delta"]["consistent"]
    assert not rows["box_pose_offset.yaw"]["consistent"]  # 20 standard errors from the hidden +0.05, of the other sign
    assert rows["pad_friction.scale"]["hidden"] == 1.0 and not rows["pad_friction.scale"]["consistent"]  # not hidden: nominal
    no_se = SimpleNamespace(parameters=[_param("box_mass", "delta", 0.05, None)])
    assert not bench.parameters_vs_hidden(no_se, hidden)[0]["consistent"]  # no standard error: nothing to vouch for it


def test_the_default_labs_truth_is_the_lab_file_and_needs_two_effects(script):
    from besdrake.transfer.lab_config import read_lab_yaml

    bench = script("bench_pnp_diagnosis")
    effects, right = bench.TRUTHS["default_lab"]
    assert effects == read_lab_yaml("pick_and_place_lab")[0]["effects"]
    assert sorted(right) == ["box_mass", "box_pose_offset"]
