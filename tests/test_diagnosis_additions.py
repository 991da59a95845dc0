"""A second effect the log cannot exclude beside a named single cause is listed (issue 25, touchdown-only logs)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from besdrake.diagnosis import fitting, settings
from besdrake.diagnosis.additions import additions_beside
from besdrake.tasks.throwing.diagnosis.model import MODEL
from besdrake.tasks.throwing.diagnosis.observables import group_slices

N_TRIALS, SD = 25, 0.05


def _world(seed: int = 3):
    """Touchdown-only features (2 per trial): a base height z the log shows (the true cause, 4 cm), a scoop roll that
    moves the touchdowns strongly along its own direction (the log rules it out), a drag that moves them by a hundredth
    of the noise per unit (nothing rules it out) and a joint-1 offset moving them exactly as the base height does
    (its twin: whatever it is, the height absorbs it)."""
    rng = np.random.default_rng(seed)
    F = MODEL.n_features
    td = group_slices()["touchdown"]
    specs = [fitting.ParamSpec("base_offset", "z", 0.0, -0.2, 0.2, 0.02, "m"),
             fitting.ParamSpec("scoop_mount", "roll", 0.0, -0.1, 0.1, 0.01, "rad"),
             fitting.ParamSpec("air_drag", "cd", 0.0, 0.0, 1.0, 0.1, "1"),
             fitting.ParamSpec("joint_offset", "joint1", 0.0, -0.1, 0.1, 0.01, "rad")]
    y0 = np.full((N_TRIALS, F), np.nan)
    y0[:, td] = rng.normal(0, 1, (N_TRIALS, 2))
    dy = np.zeros((len(specs), N_TRIALS, F))
    dz = rng.normal(0, 2.0, (N_TRIALS, 2))
    dy[0][:, td] = dz
    dy[1][:, td] = rng.normal(0, 3.0, (N_TRIALS, 2))
    dy[2][:, td] = 0.0005
    dy[3][:, td] = 2.0 * dz
    dy[~np.isfinite(np.broadcast_to(y0, dy.shape))] = np.nan
    y_meas = y0 + 0.04 * dy[0] + rng.normal(0, SD, y0.shape)
    sd = np.full(F, SD)
    prob = fitting.Problem(y_meas, y0, sd)
    sens = fitting.Sensitivity(specs, y0, np.nan_to_num(dy))
    fit = fitting.linear_fit(prob, sens, ("base_offset",))
    fit.y_fit = y0 + np.nan_to_num(dy[0]) * (fit.theta[0] - 0.0)
    fit.refined = True
    return prob, sens, fit


def test_additions_list_what_the_log_cannot_exclude_beside_the_cause():
    prob, sens, fit = _world()
    assert abs(fit.theta[0] - 0.04) < 0.005
    adds = {a.effect: a for a in additions_beside(prob, sens, fit, ["base_offset", "scoop_mount", "air_drag", "joint_offset"])}
    assert set(adds) == {"scoop_mount", "air_drag", "joint_offset"}  # the cause itself is no addition
    assert adds["scoop_mount"].excluded and adds["scoop_mount"].max_fraction < 0.05
    lo, hi = adds["scoop_mount"].allowed["roll"]
    assert lo < 0.0 < hi
    # Drag hardly moves the touchdowns: any realistic value fits beside the base height.
    assert not adds["air_drag"].excluded and adds["air_drag"].unconstrained
    # The joint-1 offset moves them as the height does: re-fitting the height absorbs it, so it is not excluded,
    # although on its own (the height held at its fit) a joint-1 offset of 10 % of its range would show clearly.
    assert not adds["joint_offset"].excluded
    assert float(np.sum(prob.weighted_jac(sens.dy[3:4]) ** 2)) * (0.1 * 0.2) ** 2 > 50.0


def test_an_outcome_only_answer_lists_the_pairs_it_cannot_exclude(monkeypatch):
    from besdrake.diagnosis import verdict
    from besdrake.diagnosis.simulate import _Sim

    prob, sens, fit = _world()
    best = SimpleNamespace(effects=("base_offset",))
    v = verdict.Verdict(True, "low", "explained by base_offset", [], [fit], best, fit, [])
    ev = SimpleNamespace(measured_groups=["touchdown"], model=MODEL, sim=_Sim(None, [], [], [], [], model=MODEL))
    verdict.possible_seconds(v, prob, sens, ev, ["base_offset", "scoop_mount", "air_drag", "joint_offset"])
    listed = {a["b"]: a for a in v.indist if a.get("addition")}
    assert set(listed) == {"air_drag + base_offset", "base_offset + joint_offset"}
    assert all(a["recommendation"] and not a["structural"] for a in listed.values())
    assert "exclude a second effect beside it" in v.text and "air_drag" in v.text and "scoop_mount" not in v.text
    assert v.confidence == "low" and {a["effect"] for a in v.basis["additions"]} == {"scoop_mount", "air_drag", "joint_offset"}
    # A pair already among the rivals is not listed twice; with a higher bar only the unconstrained drag stays.
    v = verdict.Verdict(True, "low", "", [], [fit], best, fit, [{"a": "base_offset", "b": "base_offset + joint_offset", "structural": False}])
    monkeypatch.setattr(settings, "ADDITION_MIN_FRACTION", 0.1)
    verdict.possible_seconds(v, prob, sens, ev, ["base_offset", "scoop_mount", "air_drag", "joint_offset"])
    assert [a["b"] for a in v.indist if a.get("addition")] == ["air_drag + base_offset"]


def test_the_listing_rule_keeps_what_the_data_lean_to_what_they_leave_free_and_near_pairs():
    from besdrake.diagnosis.additions import listed

    def add(e, frac, gain, free=False):
        return {"effect": e, "max_allowed_fraction_of_range": frac, "chi2_gain": gain, "unconstrained": free}

    adds = [add("ball", 0.6, 3.0), add("air_drag", 1.0, 0.0, True), add("base_offset", 0.4, 0.2), add("joint_offset", 0.05, 5.0)]
    # The excluded joint offset (allowed only within 5 % of its range) is never listed, whatever it gains.
    assert listed(adds, min_gain=1.0, unconstrained=True, pair_dbic=None) == ["ball", "air_drag"]
    assert listed(adds, min_gain=1.0, unconstrained=False, pair_dbic=None) == ["ball"]
    assert listed(adds, min_gain=0.1, unconstrained=False, pair_dbic=None) == ["ball", "base_offset"]
    # A pair fitted with rollouts within the "cannot tell" margin of the named cause is listed as well.
    assert listed(adds, min_gain=1.0, unconstrained=False, pair_dbic=6.0, refined_dbic={"base_offset": 3.9, "air_drag": 7.0}) == ["ball", "base_offset"]
    assert listed(adds, min_gain=float("inf"), unconstrained=False, pair_dbic=None) == []


def test_a_near_alias_is_one_the_cause_absorbs_within_the_high_margin():
    from besdrake.diagnosis.additions import aliases

    adds = [{"effect": "joint_offset", "per_param": {"joint4": {"absorbed": 0.94}, "joint2": {"absorbed": 0.1}}},
            {"effect": "ball", "per_param": {"mass": {"absorbed": 0.3}}}]
    singles = {"joint_offset": 6.5, "ball": 2.0, "base_offset": 7.0}
    # The joint offset is 6.5 BIC behind (beyond "cannot tell") but its joint-4 signature is nearly the cause's own:
    # listed; the ball is closer but moves the signals otherwise (a rival by the usual margin, not an alias).
    assert aliases(adds, singles, max_dbic=10.0, min_absorbed=0.9) == ["joint_offset"]
    assert aliases(adds, singles, max_dbic=6.0, min_absorbed=0.9) == []
    assert aliases(adds, singles, max_dbic=10.0, min_absorbed=0.95) == []


def test_a_second_effect_above_the_detection_limit_beside_the_cause_vetoes_high(monkeypatch):
    """Full-log rule (issue 25, benchmark trial 8): "high" needs that no other effect is allowed beside the named cause
    with a signature above the detection limit; a scoop roll hidden beside the base height is seen by its score, the
    clean world passes, and the plan-level z is recorded per parameter."""
    from besdrake.diagnosis.verdict import is_high, second_allowed, seconds_basis

    cands = ["base_offset", "scoop_mount", "air_drag", "joint_offset"]
    keys = [f"plan{i % 5}" for i in range(N_TRIALS)]
    prob, sens, fit = _world()
    clean = seconds_basis(prob, sens, fit, cands, keys)
    roll = next(r for r in clean["seconds"] if r["effect"] == "scoop_mount")
    assert roll["z_plans"] is not None and roll["max_over_limit"] >= roll["est_over_limit"] >= 0.0
    # the hidden roll: 0.01 rad moves the touchdowns by 3 cm per unit of the signature's SD direction
    prob2 = fitting.Problem(prob.y_meas + 0.01 * np.nan_to_num(sens.dy[1]), prob.y0, prob.sd)
    fit2 = fitting.linear_fit(prob2, sens, ("base_offset",))
    fit2.y_fit, fit2.refined = prob2.y0 + np.nan_to_num(sens.dy[0]) * fit2.theta[0], True
    dirty = seconds_basis(prob2, sens, fit2, cands, keys)
    assert dirty["seconds"][0]["effect"] == "scoop_mount" and dirty["seconds"][0]["est_over_limit"] > 1.0
    monkeypatch.setattr(settings, "HIGH_SECOND_Z_ALPHA", 1.645)
    monkeypatch.setattr(settings, "HIGH_SECOND_PLANS", False)
    assert second_allowed(dirty) and not second_allowed(clean)
    base = {"explained": True, "separable_rival": False, "p_value": 0.5, "outcome_only": False, "rival_margin_dbic": 50.0,
            "extra_effect_p": 0.8, "moved_parameters": 1}
    assert is_high({**base, **clean}) and not is_high({**base, **dirty})
    monkeypatch.setattr(settings, "HIGH_SECOND_Z_ALPHA", None)
    assert is_high({**base, **dirty})  # the rule switched off


def test_sensitivity_at_steps_each_parameter_on_top_of_the_fitted_cause():
    """The other effects' sensitivities where the cause has put the robot: each rollout holds the cause's effects and
    one stepped parameter of another effect, the derivative is taken against the cause's own prediction."""
    specs = [fitting.ParamSpec("scoop_mount", "roll", 0.0, -0.1, 0.1, 0.01, "rad"),
             fitting.ParamSpec("air_drag", "cd", 0.0, 0.0, 1.0, 0.1, "1")]
    base = {"gain_scale": {"kp_scale": 0.5}}
    seen = []

    def simulate(effs):
        seen.extend(effs)
        # a roll whose effect doubles when the gain is halved, a drag that ignores it
        return np.array([[[1.0 + e.get("scoop_mount", {}).get("roll", 0.0) / e["gain_scale"]["kp_scale"] + e.get("air_drag", {}).get("cd", 0.0)]]
                         for e in effs])

    sens = fitting.sensitivity_at(specs, base, np.array([[1.0]]), simulate)
    assert all(e["gain_scale"] == base["gain_scale"] for e in seen) and len(seen) == 2
    assert np.allclose(sens.dy[:, 0, 0], [2.0, 1.0])


def test_second_effects_beside_a_rival_the_answer_cannot_tell_from_are_listed(monkeypatch):
    """The joint-1 offset fits as the base height does ("cannot tell it from"): what the log allows beside it (the drag,
    which nothing constrains) is listed as that rival's pair too; the excluded scoop roll is not, nor is the named cause."""
    from besdrake.diagnosis import verdict
    from besdrake.diagnosis.simulate import _Sim

    def answer():
        prob, sens, fit = _world()
        rival = fitting.linear_fit(prob, sens, ("joint_offset",))
        rival.y_fit = prob.y0 + np.nan_to_num(sens.dy[3]) * rival.theta[0]
        rival.refined = True
        causes = [SimpleNamespace(effects=("base_offset",), delta_bic=0.0), SimpleNamespace(effects=("joint_offset",), delta_bic=0.3)]
        v = verdict.Verdict(True, "low", "explained by base_offset", causes, [fit, rival], SimpleNamespace(effects=("base_offset",)), fit,
                            [{"a": "base_offset", "b": "joint_offset", "structural": False, "delta_bic": 0.3}])
        ev = SimpleNamespace(measured_groups=["touchdown"], model=MODEL, sim=_Sim(None, [], [], [], [], model=MODEL))
        verdict.possible_seconds(v, prob, sens, ev, ["base_offset", "scoop_mount", "air_drag", "joint_offset"])
        return v

    v = answer()
    beside = {a["b"]: a for a in v.indist if a.get("beside")}
    assert set(beside) == {"air_drag + joint_offset"} and beside["air_drag + joint_offset"]["beside"] == "joint_offset"
    assert beside["air_drag + joint_offset"]["recommendation"] and "nor beside the rivals it cannot be told from: joint_offset: air_drag" in v.text
    assert {a["b"] for a in v.indist if a.get("addition") and not a.get("beside")} == {"air_drag + base_offset", "base_offset + joint_offset"}
    monkeypatch.setattr(settings, "ADDITIONS_BESIDE_RIVALS", False)
    v = answer()
    assert not any(a.get("beside") for a in v.indist) and "nor beside the rivals" not in v.text
