"""The residual report of an unexplained log: where the residual lives, what it follows, a labelled data-driven model."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from besdrake.diagnosis import fitting
from besdrake.tasks.throwing.diagnosis import observables
from besdrake.tasks.throwing.diagnosis.model import MODEL
from besdrake.tasks.throwing.diagnosis.observables import group_slices
from besdrake.diagnosis.residual import LABEL, residual_report
from besdrake.tasks.throwing.throws import default_throw


def _fake_log(n: int = 24, seed: int = 0, slope: float = 0.3):
    """Throws whose touchdown residual is ``slope`` x the nominal sideways release speed (a cross wind-like effect the
    registry does not know), plus 2 cm noise; the other groups fit."""
    rng = np.random.default_rng(seed)
    sl = group_slices()
    F = observables.N_FEATURES
    y0 = np.zeros((n, F))
    y0[:, sl["touchdown"]] = np.column_stack([rng.uniform(1, 2.5, n), rng.uniform(-0.5, 0.5, n)])
    y0[:, sl["ball_vel"]] = np.column_stack([rng.uniform(2, 3.5, n), rng.uniform(-0.4, 0.4, n), rng.uniform(0.5, 1.2, n)])
    y0[:, sl["ball_pos"]] = rng.uniform(0.5, 1.0, (n, 3))
    y_meas = y0 + rng.normal(0, 1e-4, (n, F))
    y_meas[:, sl["touchdown"]] += rng.normal(0, 0.02, (n, 2))
    y_meas[:, sl["touchdown"].start + 1] += slope * y0[:, sl["ball_vel"].start + 1]
    plans = [default_throw(amplitude=0.25 + 0.01 * i) for i in range(n)]
    sim = SimpleNamespace(full_cache={"{}": y0}, key=lambda e: "{}")
    ev = SimpleNamespace(used=[SimpleNamespace(trial=i) for i in range(n)], plans=plans, keys=[f"p{i}" for i in range(n)], sim=sim,
                         y0=y0, y_meas=y_meas, measured_groups=["touchdown", "ball_vel"], model=MODEL)
    sd = np.full((n, F), np.nan)
    sd[:, sl["touchdown"]] = 0.02
    sd[:, sl["ball_vel"]] = 1e-3
    return ev, fitting.Problem(y_meas, y0, sd)


def test_the_residual_is_located_and_its_data_driven_model_gains_held_out():
    ev, prob = _fake_log()
    rep = residual_report(ev, prob, ev.y0, folds=3, rng=np.random.default_rng(0))
    assert max(rep.group_share, key=rep.group_share.get) == "touchdown"
    assert rep.follows and rep.follows[0]["feature"] == "vel_y" and rep.follows[0]["axis"] == "y" and rep.follows[0]["r"] > 0.5
    m = rep.model
    assert m["label"] == LABEL and m["better"] and m["heldout_after_m"] < 0.8 * m["heldout_before_m"]
    assert "not a physical cause" in rep.describe() or "data-driven" in rep.describe()


def test_without_a_pattern_the_model_claims_no_gain_and_nothing_is_followed():
    ev, prob = _fake_log(slope=0.0, seed=3)
    rep = residual_report(ev, prob, ev.y0, folds=3, rng=np.random.default_rng(0))
    assert rep.follows == []
    assert rep.model["heldout_after_m"] >= 0.8 * rep.model["heldout_before_m"]


def test_without_a_pattern_no_model_is_offered_and_the_verdict_says_no_gain():
    ev, prob = _fake_log(slope=0.0, seed=3)
    rep = residual_report(ev, prob, ev.y0, folds=3, rng=np.random.default_rng(0))
    assert not rep.model["offered"] and "no gain" in rep.describe()


def _cases(n: int = 30, seed: int = 0, slope: float = 0.04):
    """Behaviour-like features (one of 9 carries the residual), plans with repeats, 5 cm touchdown noise."""
    rng = np.random.default_rng(seed)
    groups = np.arange(n) % 20
    X = rng.normal(size=(20, 9))[groups]
    Y = rng.normal(0.0, 0.05, (n, 2))
    Y[:, 1] += slope * X[:, 4]
    return X, Y, groups


def test_the_cross_validated_error_is_exact_leave_one_plan_out():
    from besdrake.diagnosis.residual_model import _cv_errors, _group_rows

    X, Y, groups = _cases()
    Z = (X - X.mean(axis=0)) / X.std(axis=0)
    for cols, alpha, icpt in (([4], 0.1, True), ([1, 4, 7], 0.03, False), ([], 1.0, True)):
        brute = 0.0
        for g in np.unique(groups):
            t = groups == g
            A = np.column_stack(([np.ones((~t).sum())] if icpt else []) + [Z[~t, j] for j in cols])
            P = np.diag([0.0] * icpt + [alpha * len(Z)] * len(cols))
            c = np.linalg.solve(A.T @ A + P, A.T @ Y[~t])
            At = np.column_stack(([np.ones(t.sum())] if icpt else []) + [Z[t, j] for j in cols])
            brute += np.sum((Y[t] - At @ c) ** 2)
        assert abs(_cv_errors(Z, Y, _group_rows(groups), cols, alpha, icpt).sum() - brute) < 1e-9


def test_the_model_keeps_the_feature_the_residual_follows_and_only_it():
    from besdrake.diagnosis.residual_model import ResidualModel

    picked = [ResidualModel().fit(*_cases(seed=s, slope=0.08)).features_ for s in range(5)]
    assert sum(4 in p for p in picked) == 5 and np.mean([len(p) for p in picked]) <= 1.6
    empty = [ResidualModel().fit(*_cases(seed=s, slope=0.0)).kind_ for s in range(5)]
    assert empty.count("ridge") <= 2  # measured 2 of 5: the selection alone is permissive; the nested held-out gain decides the offer


def test_the_model_does_not_extrapolate_and_survives_json():
    import json

    from besdrake.diagnosis.residual_model import ResidualModel

    X, Y, groups = _cases(slope=0.08)
    m = ResidualModel().fit(X, Y, groups)
    names = [f"f{j}" for j in range(9)]
    far = X[:1].copy()
    far[0, 4] = 1e3
    edge = X[:1].copy()
    edge[0, 4] = X[:, 4].max()
    assert np.allclose(m.predict(far), m.predict(edge))
    back = ResidualModel.from_dict(json.loads(json.dumps(m.describe(names))), names)
    assert np.allclose(back.predict(X), m.predict(X))
