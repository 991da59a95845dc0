"""The within-trial noise covariance (issue 25): one trial's perturbation moves several of its features together."""

from __future__ import annotations

import numpy as np
import pytest

from besdrake.diagnosis import fitting, noise, settings
from besdrake.diagnosis.verdict import strongest_extra
from besdrake.tasks.throwing.diagnosis.observables import N_FEATURES, group_slices


@pytest.fixture(autouse=True)
def _covariance_model_on(monkeypatch):
    """These tests exercise the within-trial covariance model whatever the defaults say (on for logs beyond the
    outcome since session 50)."""
    monkeypatch.setattr(settings, "WITHIN_TRIAL_COVARIANCE", True)
    monkeypatch.setattr(settings, "WITHIN_TRIAL_COVARIANCE_OUTCOME_ONLY", False)


def _repeats(rng: np.random.Generator, plans: int = 10, per: int = 2, shared: float = 0.05) -> tuple[np.ndarray, list[str]]:
    """Features of repeated plans whose touchdown x and horizontal ball position x share one perturbation per trial
    (the path's x moves by half the touchdown's), everything else independent."""
    sl = group_slices()
    keys = [f"p{j}" for j in range(plans) for _ in range(per)]
    f = np.zeros((len(keys), N_FEATURES))
    for i in range(len(keys)):
        delta = rng.normal(0, shared)
        f[i] = rng.normal(0, 1e-3, N_FEATURES)
        f[i, sl["touchdown"].start] += delta
        f[i, sl["ball_pos"].start] += 0.5 * delta
        f[i, sl["touchdown"].start + 1] += rng.normal(0, shared)
        f[i, sl["ball_pos"].start + 1] += rng.normal(0, 0.5 * shared)
    return f, keys


def test_base_correlation_finds_a_shared_perturbation_and_nothing_else():
    rng = np.random.default_rng(3)
    f, keys = _repeats(rng)
    nm = noise.estimate_noise(f, keys)
    sl = group_slices()
    tx, px, ty, py = sl["touchdown"].start, sl["ball_pos"].start, sl["touchdown"].start + 1, sl["ball_pos"].start + 1
    R = nm.base_corr
    assert R is not None and R[tx, px] > 0.9
    off = R - np.eye(N_FEATURES)
    off[tx, px] = off[px, tx] = 0.0
    # The independent y's (and everything else) stay uncorrelated; the eigenvalues stay positive.
    assert abs(R[ty, py]) < 1e-9 and np.max(np.abs(off)) < 0.05
    assert np.linalg.eigvalsh(R).min() > 0


def test_whitened_problem_is_generalised_least_squares():
    rng = np.random.default_rng(4)
    f, keys = _repeats(rng)
    nm = noise.estimate_noise(f, keys)
    n = len(f)
    cov = nm.covariances(n)
    sd = nm.matrix(n)
    assert np.allclose(np.einsum("nii->ni", cov), sd**2)
    y0 = np.zeros_like(f)
    prob = fitting.Problem(f, y0, sd, cov=cov)
    r = prob.weighted(y0)
    # chi2 = sum over trials of e_i^T Sigma_i^-1 e_i
    gls = sum(float(f[i] @ np.linalg.solve(cov[i], f[i])) for i in range(n))
    assert float(r @ r) == pytest.approx(gls, rel=1e-6)
    # The shared perturbation counts once: the whitened chi2 is below the diagonal one (which counts it twice).
    diag = fitting.Problem(f, y0, sd)
    assert float(r @ r) < float(diag.weighted(y0) @ diag.weighted(y0))
    # weighted_jac and unweighted are inverse maps; a group's chi2 uses its own block.
    dy = rng.normal(size=(1, *f.shape))
    J = prob.weighted_jac(dy)[:, 0]
    assert np.allclose(prob.weighted_jac(prob.unweighted(J)[None])[:, 0], J)
    td = group_slices()["touchdown"]
    c2 = fitting.chi2_by_group(prob, y0, {"touchdown": td})["touchdown"]
    assert c2 == pytest.approx(sum(float(f[i, td] @ np.linalg.solve(cov[i][td, td], f[i, td])) for i in range(n)), rel=1e-6)


@pytest.mark.parametrize("floor", [1e-3, 0.1])
def test_a_near_exact_correlation_is_trusted_only_down_to_the_eigenvalue_floor(monkeypatch, floor):
    """Two features that move together almost exactly (one perturbation, tiny independent noise) leave a contrast the
    repeats put near nil; its weight in the whitening is bounded by the floor on the correlation's eigenvalues."""
    monkeypatch.setattr(settings, "CORRELATION_EIGENVALUE_FLOOR", floor)
    f, keys = _repeats(np.random.default_rng(7), plans=12, shared=0.05)
    R = noise.estimate_noise(f, keys).base_corr
    ev = np.linalg.eigvalsh(R)
    assert ev.min() >= floor / (1.0 + floor) - 1e-12
    assert ev.min() < max(1.5 * floor, 0.01)  # the contrast: near nil, or at the floor


def test_diagonal_switch_and_floor():
    rng = np.random.default_rng(5)
    f, keys = _repeats(rng)
    nm = noise.estimate_noise(f, keys)
    old = settings.WITHIN_TRIAL_COVARIANCE
    try:
        settings.WITHIN_TRIAL_COVARIANCE = False
        assert nm.covariances(len(f)) is None
    finally:
        settings.WITHIN_TRIAL_COVARIANCE = old
    # A feature whose SD is the simulation floor stays independent of every other.
    cov = nm.covariances(len(f))
    j = group_slices()["joints"].start
    assert np.allclose(np.delete(cov[:, j], j, axis=1), 0.0)


def test_outcome_only_log_keeps_the_diagonal_model_unless_asked(monkeypatch):
    """A log of touchdowns alone: the outcome's x and y share a perturbation, but the covariance is used only when the
    outcome-only switch is on; a full log of the same trials uses it."""
    rng = np.random.default_rng(6)
    sl = group_slices()
    keys = [f"p{j}" for j in range(10) for _ in range(2)]
    f = np.full((len(keys), N_FEATURES), np.nan)
    td = sl["touchdown"]
    shared = rng.normal(0, 0.05, len(keys))
    f[:, td] = rng.normal(0, 0.01, (len(keys), td.stop - td.start))
    f[:, td.start] += shared
    f[:, td.start + 1] += shared
    nm = noise.estimate_noise(f, keys)
    assert nm.outcome_only and nm.base_corr is not None
    assert nm.covariances(len(f)) is None
    monkeypatch.setattr(settings, "WITHIN_TRIAL_COVARIANCE_OUTCOME_ONLY", True)
    cov = nm.covariances(len(f))
    assert cov is not None and cov[0, td.start, td.start + 1] > 0
    full, _ = _repeats(rng)
    assert not noise.estimate_noise(full, keys).outcome_only


def test_added_effect_judged_against_the_repeats_dof():
    from besdrake.diagnosis.results import Cause

    def cause(effects, chi2, k):
        return Cause(tuple(effects), [], 0.0, 0.0, chi2, 1000, k, True, 0.5, [], {}, float(k), [], 0.0)

    causes = [cause(["joint_offset"], 120.0, 1), cause(["joint_offset", "ball"], 100.0, 2)]
    p_known, _ = strongest_extra(causes)
    old = settings.SCALED_EXTRA_TEST
    try:
        settings.SCALED_EXTRA_TEST = True
        p_scaled, _ = strongest_extra(causes, nu=8)
        assert strongest_extra(causes, nu=8, scale=4.0)[0] > p_scaled  # more noise along the direction: weaker evidence
        settings.SCALED_EXTRA_TEST = False
        assert strongest_extra(causes, nu=8)[0] == p_known
    finally:
        settings.SCALED_EXTRA_TEST = old
    assert p_known < 1e-4 < p_scaled < 0.05  # 20 chi2 for one parameter: chi2(1) p 8e-6, F(1, 8) p 0.002


def test_repeat_scale_measures_the_noise_along_a_direction():
    from besdrake.diagnosis.stats import _repeat_scale

    rng = np.random.default_rng(6)
    plans, per, F = 40, 2, 3
    keys = [f"p{j}" for j in range(plans) for _ in range(per)]
    y0 = np.repeat(rng.normal(size=(plans, F)), per, axis=0)
    sd = np.ones(F)
    noise_ = rng.normal(size=y0.shape)
    noise_[:, 0] *= 3.0  # the model says 1, the lab scatters 3x along feature 0
    prob = fitting.Problem(y0 + noise_, y0, sd)
    u0 = np.zeros((len(keys), F))
    u0[:, 0] = 1.0
    u1 = np.zeros((len(keys), F))
    u1[:, 1] = 1.0
    s0, nu0 = _repeat_scale(prob, u0[prob.mask], keys)
    s1, nu1 = _repeat_scale(prob, u1[prob.mask], keys)
    assert nu0 == pytest.approx(plans) and 5.0 < s0 < 14.0 and 0.5 < s1 < 1.6
    assert _repeat_scale(prob, u0[prob.mask], [f"q{i}" for i in range(len(keys))]) == (1.0, 0.0)  # no repeats
