"""The plan jackknife behind "high" (issue 25): a named cause whose lead one plan makes is not vouched for."""

from __future__ import annotations

import numpy as np
import pytest

from besdrake.diagnosis import settings
from besdrake.diagnosis.fitting import CandidateFit, ParamSpec, Problem
from besdrake.diagnosis.jackknife import jackknife_margin, left_out_bics, plan_rows
from besdrake.diagnosis.verdict import is_high

KEYS = [f"plan{j}" for j in range(6) for _ in range(2)]  # 6 plans thrown twice each: 12 trials


def _fit(prob: Problem, dy: np.ndarray | None, theta: float | None) -> CandidateFit:
    """A fit of one parameter with feature derivatives ``dy`` (N, F) at ``theta`` (None: the nominal model)."""
    if dy is None:
        return CandidateFit((), [], np.zeros(0), np.zeros(0), chi2=float(np.sum(prob.weighted(prob.y0) ** 2)), n=prob.n, k=0,
                            refined=True, y_fit=prob.y0.copy(), jac=np.zeros((prob.n, 0)))
    spec = ParamSpec("test", "a", 0.0, -10.0, 10.0, 0.01, "m")
    y = prob.y0 + theta * dy
    return CandidateFit(("test",), [spec], np.array([theta]), np.array([0.1]), chi2=float(np.sum(prob.weighted(y) ** 2)), n=prob.n, k=1,
                        refined=True, y_fit=y, jac=prob.weighted_jac(dy[None]))


def _problem(y_first: np.ndarray) -> Problem:
    y = np.zeros((len(KEYS), 2))
    y[:, 0] = y_first
    y[:, 1] = np.tile([0.3, -0.3], len(KEYS) // 2)
    return Problem(y, np.zeros_like(y), np.ones(2))


def test_plans_group_a_logs_repeats():
    assert plan_rows(["a", "b", "a", "c", "b"]) == [[0, 2], [1, 4], [3]]


def test_a_lead_every_plan_shares_survives_leaving_any_plan_out():
    prob = _problem(np.full(len(KEYS), 1.5) + np.tile([0.1, -0.1], len(KEYS) // 2))
    dy = np.zeros((len(KEYS), 2))
    dy[:, 0] = 1.0
    named, nominal = _fit(prob, dy, 1.5), _fit(prob, None, None)
    assert nominal.bic - named.bic > 20  # the full log's lead
    jk = jackknife_margin(prob, named, [nominal], KEYS)
    assert 15 < jk.margin_dbic < nominal.bic - named.bic and jk.rival == nominal.name and len(jk.left_out) == 2


def test_a_lead_one_plan_makes_is_gone_without_it():
    y = np.zeros(len(KEYS))
    y[[4, 5]] = 3.5  # plan 2 alone shows the effect
    prob = _problem(y)
    dy = np.zeros((len(KEYS), 2))
    dy[[4, 5], 0] = 1.0  # ... and the named effect moves only that plan
    named, nominal = _fit(prob, dy, 3.5), _fit(prob, None, None)
    assert nominal.bic - named.bic > settings.HIGH_MARGIN_DBIC  # "high" by the full log's margin alone
    jk = jackknife_margin(prob, named, [nominal], KEYS)
    assert jk.margin_dbic < 0 and jk.left_out == (4, 5)
    # the refit without a plan is exact for a linear model: the named cause's chi2 without plan 2 is the rest's
    bics = left_out_bics(prob, named, plan_rows(KEYS))
    rest = np.ones(len(KEYS), bool)
    rest[[4, 5]] = False
    assert bics[2] - named.k_eff * np.log(prob.n - 4) == pytest.approx(np.sum(prob.y_meas[rest] ** 2), rel=1e-6)


def test_the_jackknife_vetoes_high_and_can_be_switched_off():
    basis = {"explained": True, "separable_rival": False, "p_value": 0.5, "outcome_only": False, "rival_margin_dbic": 14.5,
             "extra_effect_p": 0.8, "moved_parameters": 1}
    assert is_high(basis) and is_high({**basis, "jackknife_margin_dbic": None})  # no rival refitted, or a basis from before
    assert not is_high({**basis, "jackknife_margin_dbic": 1.0})  # seed 6 trial 42's figures
    assert is_high({**basis, "jackknife_margin_dbic": 1.0}, jackknife_dbic=None)
    assert is_high({**basis, "jackknife_margin_dbic": settings.HIGH_JACKKNIFE_DBIC + 0.1})


def test_too_few_plans_or_no_refined_fit_give_no_margin():
    prob = _problem(np.ones(len(KEYS)))
    dy = np.ones((len(KEYS), 2))
    named = _fit(prob, dy, 1.0)
    assert jackknife_margin(prob, named, [_fit(prob, None, None)], ["a", "b"] * 6).margin_dbic == float("inf")
    unrefined = CandidateFit(("x",), [], np.zeros(0), np.zeros(0), chi2=1.0, n=prob.n, k=0)
    assert jackknife_margin(prob, named, [unrefined], KEYS).margin_dbic == float("inf")


def test_the_note_names_the_plan_and_the_rival():
    from besdrake.diagnosis.verdict import jackknife_note

    note = jackknife_note({"jackknife_margin_dbic": 1.0, "jackknife_rival": "base_offset + joint_offset", "jackknife_left_out": [21]})
    assert "trials 21" in note and "base_offset + joint_offset" in note and "1.0 BIC" in note
