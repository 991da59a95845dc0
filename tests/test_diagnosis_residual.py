"""The residual report of an unexplained log: where the residual lives, what it follows, a labelled data-driven model."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from besdrake.diagnosis import fitting, observables
from besdrake.diagnosis.observables import group_slices
from besdrake.diagnosis.residual import LABEL, residual_report
from besdrake.sim.throws import default_throw


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
                         y0=y0, y_meas=y_meas, measured_groups=["touchdown", "ball_vel"])
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
