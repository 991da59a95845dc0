"""scripts/bench_diagnosis.py: the noise-free signature of a hidden effect and its size against the detection limit."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from besdrake.diagnosis.core import INDISTINGUISHABLE_DBIC
from besdrake.diagnosis.design import diagnosis_plans
from besdrake.tasks.throwing.diagnosis.observables import N_FEATURES, group_slices

def test_signature_is_the_effect_on_minus_off_without_noise(script):
    from besdrake.sim import Rollout
    from besdrake.tasks.throwing.lab import VirtualLab

    bench = script("bench_diagnosis")
    plans = diagnosis_plans(3, 0, seed=3)
    hidden = {"base_offset": {"z": -0.05}}
    ms = [VirtualLab({"name": "t", "effects": hidden, "seed": 9}).execute(p, trial=i) for i, p in enumerate(plans)]
    roll = Rollout("nominal")
    td = group_slices()["touchdown"]
    sig = bench._signature(hidden, 9, ms, plans, roll)
    exp = bench._expected_signature(hidden, ms, plans, roll, 0.002, n_draws=1, seed=9)
    assert sig.shape == exp.shape == (3, N_FEATURES)
    # A 5 cm lower pedestal lands the ball centimetres short, with or without the placement scatter averaged.
    assert np.all(np.abs(sig[:, td.start]) > 0.01) and np.all(np.abs(exp[:, td.start]) > 0.01)
    assert np.allclose(sig[:, td], exp[:, td], atol=0.01)
    # No effect: nothing moves (same placement draws on and off).
    assert np.allclose(np.nan_to_num(bench._signature({}, 9, ms, plans, roll)), 0.0)


def test_signature_size_is_in_units_of_the_detection_limit(script):
    bench = script("bench_diagnosis")
    sl = group_slices()
    sd = np.ones(N_FEATURES)
    sd[sl["touchdown"]] = 0.05
    per_throw = np.tile(sd, (10, 1))
    per_throw[0, sl["touchdown"]] = 0.1  # the diagnosis weighs the first throw half (its placement scatters it)
    d = SimpleNamespace(noise=SimpleNamespace(vector=lambda: sd, matrix=lambda n: per_throw[:n]), n_used=10,
                        groups_measured=["touchdown"], causes=[SimpleNamespace(n=50)])
    sig = np.full((10, N_FEATURES), np.nan)
    sig[:, sl["touchdown"]] = [0.05, 0.0]  # one noise SD on every throw's touchdown x
    sig[:, sl["ball_pos"]] = 1.0  # not logged: does not count
    out = bench._signature_size(sig, d, k=1)
    assert out["signature_chi2"] == pytest.approx(9.25)
    assert out["detection_limit_chi2"] == pytest.approx(INDISTINGUISHABLE_DBIC + np.log(50))
    assert out["signature_over_limit"] == pytest.approx(9.25 / (INDISTINGUISHABLE_DBIC + np.log(50)))
    assert set(out["signature_chi2_by_group"]) == {"touchdown"}
    # A trial the diagnosis did not use: the rows do not line up, the group SDs count.
    d.n_used = 9
    assert bench._signature_size(sig, d, k=1)["signature_chi2"] == pytest.approx(10.0)


def test_full_range_draws_cover_every_parameter_in_both_directions(script):
    from besdrake.sim.effects import get_effect
    from besdrake.task import effects_for

    bench = script("bench_diagnosis")
    registry = effects_for("throwing")
    cases = bench.full_range_cases(registry)
    # the ball smaller and larger, gains down and up, every joint both ways, base roll/pitch/yaw, the scoop mount
    for case in [("ball", "radius", -1), ("ball", "radius", 1), ("gain_scale", "kp_scale", -1), ("gain_scale", "kp_scale", 1),
                 ("base_offset", "roll", -1), ("base_offset", "pitch", 1), ("base_offset", "yaw", -1), ("scoop_mount", "pitch", 1)]:
        assert case in cases
    assert all(("joint_offset", f"joint{k}", s) in cases for k in range(1, 7) for s in (-1, 1))
    assert ("actuator_lag", "delay", -1) not in cases  # no room below a zero delay
    seen, pairs = set(), 0
    for i in range(len(cases)):
        hidden = bench.draw_full(i, registry, np.random.default_rng([0, i]), pair_every=3)
        pairs += len(hidden) == 2
        for e, vals in hidden.items():
            get_effect(e).complete(vals)  # valid values within the realistic bounds
            for k, v in vals.items():
                p = get_effect(e).params[k]
                seen.add((e, k, int(np.sign(v - p.nominal))))
    assert {c for c in cases} <= seen and pairs == len(cases) // 3


def test_structurally_identical_answers_count_as_right_and_reliability_is_per_level(script):
    bench = script("bench_diagnosis")
    cls = [{"members": ["base_offset.yaw", "joint_offset.joint1"]}]
    assert bench.equivalent_answer(("base_offset",), {"base_offset": {"yaw": 0.05}}, {"joint_offset": {"joint1": 0.05}}, cls)
    assert not bench.equivalent_answer(("base_offset",), {"base_offset": {"z": 0.05}}, {"joint_offset": {"joint1": 0.05}}, cls)
    rows = [{"trial": 0, "confidence": "high", "correct": True, "correct_structural": True, "honest_cannot_tell": False, "hidden": {}, "best": []},
            {"trial": 1, "confidence": "high", "correct": False, "correct_structural": False, "honest_cannot_tell": False, "hidden": {}, "best": []},
            {"trial": 2, "confidence": "low", "correct": False, "correct_structural": False, "honest_cannot_tell": True, "hidden": {}, "best": []}]
    rel = bench.reliability(rows)
    assert rel["high"]["n"] == 2 and rel["high"]["share_right"] == 0.5 and [w["trial"] for w in rel["high"]["wrong_trials"]] == [1]
    assert rel["low"]["right_or_honest"] == 1 and rel["low"]["wrong"] == 0


def test_the_residual_model_summary_counts_offered_trials_checked_on_fresh_throws(script):
    bench = script("bench_diagnosis")
    rows = [{"trial": 0, "hidden": {}, "residual_offered": True, "residual_kind": "ridge", "residual_features": ["vel_y"], "residual_heldout_before_m": 0.10,
             "residual_heldout_after_m": 0.07, "fresh_before_m": 0.11, "fresh_after_m": 0.08},
            {"trial": 1, "hidden": {}, "residual_offered": True, "residual_kind": "offset", "residual_features": [], "residual_heldout_before_m": 0.08,
             "residual_heldout_after_m": 0.07, "fresh_before_m": 0.07, "fresh_after_m": 0.09},
            {"trial": 2, "hidden": {}, "residual_offered": False, "residual_kind": "none", "residual_features": [], "residual_heldout_before_m": 0.08,
             "residual_heldout_after_m": 0.08, "fresh_before_m": 0.07, "fresh_after_m": 0.07},
            {"trial": 3, "hidden": {}, "explained": True}]
    s = bench._residual_summary(rows)
    assert s["trials_with_residual_report"] == 3 and s["offered"] == 2 and s["offered_heldout_lower"] == 2
    assert s["offered_fresh_checked"] == 2 and s["offered_fresh_lower"] == 1 and s["share_offered_fresh_lower"] == 0.5
    assert s["fitted_not_offered_fresh_checked"] == 0 and [r["trial"] for r in s["per_trial"]] == [0, 1, 2]


def test_confidence_sweep_re_decides_high_from_the_recorded_basis(script):
    bench = script("bench_diagnosis")
    basis = {"explained": True, "separable_rival": False, "p_value": 0.5, "outcome_only": False, "rival_margin_dbic": 12.0,
             "extra_effect_p": 0.3, "moved_parameters": 1}
    right = {"trial": 0, "unknown": False, "confidence": "high", "correct": True, "correct_structural": True, "explained": True,
             "best": ["ball"], "hidden": {"ball": {"radius": 0.03}}, "confidence_basis": basis, "fitted": {"ball": {"radius": 0.03}}}
    wrong = {**right, "trial": 1, "correct": False, "correct_structural": False, "best": ["joint_offset"],
             "confidence_basis": {**basis, "moved_parameters": 3}}
    sweep = {(r["margin_dbic"], r["extra_p"], r["max_moved"]): r for r in bench.confidence_sweep([right, wrong], [])}
    assert sweep[(10.0, 0.05, 99)]["high"] == 2 and sweep[(10.0, 0.05, 99)]["confident_wrong"] == 1
    assert sweep[(10.0, 0.05, 2)]["high"] == 1 and sweep[(10.0, 0.05, 2)]["confident_wrong"] == 0
    assert sweep[(15.0, 0.05, 99)]["high"] == 0  # both leads of 12 BIC fall short of 15
    assert bench._wrong_kind({"best": ["ball"], "hidden": {"ball": {}, "air_drag": {}}}) == "incomplete"
    assert bench._wrong_kind({"best": ["ball", "gain_scale"], "hidden": {"ball": {}, "air_drag": {}}}) == "false claim"


def test_resummarize_pools_the_rows_of_several_seeds(script, tmp_path):
    """Several seeds' outputs summarised as one benchmark: every row counts once, tagged with its file's seed, so a wrong
    "high" answer names the run it came from."""
    import json

    bench = script("bench_diagnosis")
    stored = sorted((bench.Path(bench.__file__).parent / "results").glob("bench_diagnosis_full_seed[23]_*s29.json"))
    assert len(stored) >= 2
    one = json.loads(stored[0].read_text())
    alone = bench._resummarize([str(stored[0])])["full"]
    assert alone["n_known_trials"] == one["full"]["n_known_trials"]
    assert alone["reliability"]["high"]["n"] == one["full"]["reliability"]["high"]["n"]
    # A copy with another seed and one answer turned confidently wrong.
    other = json.loads(json.dumps(one))
    other["config"]["seed"] = 99
    row = next(r for r in other["trials"] if r["mode"] == "full" and r["confidence"] == "high" and not r["unknown"])
    row.update(correct=False, correct_structural=False, correct_detectable=False)
    (tmp_path / "other.json").write_text(json.dumps(other))
    pooled = bench._resummarize([str(stored[0]), str(tmp_path / "other.json")])
    assert pooled["full"]["n_known_trials"] == 2 * alone["n_known_trials"]
    assert pooled["full"]["reliability"]["high"]["n"] == 2 * alone["reliability"]["high"]["n"]
    assert pooled["full"]["confident_wrong"] == 2 * alone["confident_wrong"] + 1
    wrong = pooled["full"]["reliability"]["high"]["wrong_trials"]
    assert {"seed": 99, "trial": row["trial"]}.items() <= next(w for w in wrong if w.get("seed") == 99).items()
    assert [p["seed"] for p in pooled["config"]["pooled"]] == [one["config"]["seed"], 99]
