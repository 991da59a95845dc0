"""Gaussian process, acquisition functions, entropy search / MRS machinery and the BO optimizer."""

import numpy as np
import pytest

from besdrake.search.acquisition import expected_improvement, upper_confidence_bound
from besdrake.search.base import load_state, save_state
from besdrake.search.bayesopt import BayesianOptimizer
from besdrake.search.entropy_search import RepresenterModel, discrete_entropy, entropy_search, select_representers
from besdrake.search.gp import GaussianProcess
from besdrake.search.mrs import minimum_regret_search

BRANIN_BOUNDS = np.array([[-5.0, 10.0], [0.0, 15.0]])
BRANIN_MIN = 0.397887


def branin(X):
    X = np.atleast_2d(X)
    x1, x2 = X[:, 0], X[:, 1]
    b, c, t = 5.1 / (4 * np.pi**2), 5 / np.pi, 1 / (8 * np.pi)
    return (x2 - b * x1**2 + c * x1 - 6) ** 2 + 10 * (1 - t) * np.cos(x1) + 10


def fitted_gp(n=12, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-2, 2, size=(n, 1))
    y = np.sin(2 * X[:, 0]) * 3.0 + 10.0
    return GaussianProcess(np.array([[-2.0, 2.0]]), seed=1).fit(X, y), X, y


# ---------------------------------------------------------------------------- GP
def test_gp_interpolates_and_is_uncertain_away_from_data():
    gp, X, y = fitted_gp()
    mean, std = gp.predict(X, return_std=True)
    np.testing.assert_allclose(mean, y, atol=0.05)
    Xq = np.linspace(-2, 2, 41)[:, None]
    mq = gp.predict(Xq)
    assert np.max(np.abs(mq - (np.sin(2 * Xq[:, 0]) * 3 + 10))) < 0.5
    _, std_out = gp.predict(np.array([[5.0]]), return_std=True)  # far outside the data
    assert std_out[0] > 10 * std.max()


def test_gp_posterior_covariance_is_consistent_with_predict():
    gp, _, _ = fitted_gp()
    Xq = np.linspace(-2, 2, 15)[:, None]
    mean, cov = gp.posterior(Xq)
    m2, s2 = gp.predict(Xq, return_std=True)
    np.testing.assert_allclose(mean, m2)
    np.testing.assert_allclose(np.sqrt(np.clip(np.diag(cov), 1e-16, None)), s2, rtol=1e-6, atol=1e-7)
    assert np.allclose(cov, cov.T)
    assert np.linalg.eigvalsh(cov).min() > -1e-8 * np.trace(cov)


def test_gp_rejects_bad_input():
    gp = GaussianProcess(np.array([[0.0, 1.0]]))
    with pytest.raises(ValueError, match="finite"):
        gp.fit(np.array([[0.1], [0.2]]), np.array([1.0, np.nan]))
    with pytest.raises(ValueError, match="shape"):
        gp.fit(np.zeros((3, 2)), np.zeros(3))
    with pytest.raises(ValueError, match="upper limit"):
        GaussianProcess(np.array([[1.0, 0.0]]))
    with pytest.raises(RuntimeError, match="not fitted"):
        gp.predict(np.zeros((1, 1)))


def test_gp_state_roundtrip_predicts_identically(tmp_path):
    gp, _, _ = fitted_gp()
    save_state(gp.state_dict(), tmp_path / "gp")
    restored = GaussianProcess.from_state(load_state(tmp_path / "gp"))
    Xq = np.linspace(-3, 3, 9)[:, None]
    np.testing.assert_allclose(restored.predict(Xq, return_std=True), gp.predict(Xq, return_std=True), rtol=1e-10)


# ---------------------------------------------------------------------------- acquisitions
def test_ucb_and_ei_formulas():
    gp, X, _ = fitted_gp()
    Xq = np.linspace(-2, 2, 21)[:, None]
    mean, std = gp.predict(Xq, return_std=True)
    np.testing.assert_allclose(upper_confidence_bound(gp, Xq, kappa=1.5), mean + 1.5 * std)
    ei = expected_improvement(gp, Xq, incumbent=float(mean.max()))
    assert (ei >= 0).all()
    # EI is at least the plain improvement and grows with the uncertainty
    assert (ei >= np.clip(mean - mean.max(), 0, None) - 1e-12).all()
    assert expected_improvement(gp, np.array([[5.0]]), incumbent=float(mean.max()))[0] > ei.max()


# ---------------------------------------------------------------------------- entropy search machinery
def test_pathwise_fantasy_samples_match_exact_gp_conditioning():
    """The fantasised joint samples must have the moments of the Gaussian conditioned on the fantasy."""
    gp, X, y = fitted_gp(n=6)
    rng = np.random.default_rng(0)
    R = np.linspace(-2, 2, 7)[:, None]
    x_new = np.array([[0.37]])
    model = RepresenterModel(gp, R, rng, n_samples=40000, n_fantasies=3)
    (_, f, m), = list(model.fantasies(x_new))
    node = 2  # the largest Gauss-Hermite node: y = mean + sqrt(3) * sd_y
    joint_mean, joint_cov = gp.posterior(np.vstack([R, x_new]))
    var_y = joint_cov[-1, -1] + gp.noise_variance
    y_new = joint_mean[-1] + model.nodes[node] * np.sqrt(var_y)
    cross = joint_cov[:-1, -1]
    exact_mean = joint_mean[:-1] + cross * (y_new - joint_mean[-1]) / var_y
    exact_cov = joint_cov[:-1, :-1] - np.outer(cross, cross) / var_y
    np.testing.assert_allclose(m[0, node, 0], exact_mean, rtol=1e-9)
    samples = f[0, node, :, 0, :].T  # (R, S)
    scale = np.sqrt(exact_cov.diagonal().max())
    np.testing.assert_allclose(samples.mean(axis=1), exact_mean, atol=0.03 * scale)
    assert np.max(np.abs(np.cov(samples) - exact_cov)) < 0.05 * scale**2
    # and the fantasy really changed the covariance (else the test would be vacuous)
    assert np.max(np.abs(exact_cov - joint_cov[:-1, :-1])) > 0.2 * scale**2


def test_p_max_is_a_distribution_and_information_gain_prefers_uncertain_candidates():
    gp, X, _ = fitted_gp(n=5)
    rng = np.random.default_rng(1)
    pool = np.linspace(-2, 2, 200)[:, None]
    reps = select_representers(gp, pool, 20, rng)
    assert reps.shape == (20, 1)
    model = RepresenterModel(gp, reps, rng, n_samples=512)
    p = model.p_max()
    assert p.shape == (1, 20) and np.isclose(p.sum(), 1.0)
    assert np.isclose(model.entropy(), discrete_entropy(p).sum())
    _, std = gp.predict(pool, return_std=True)
    at_data = X[[0]]
    uncertain = reps[[int(np.argmax(gp.predict(reps, return_std=True)[1]))]]
    gains = model.information_gain(np.vstack([at_data, uncertain]))
    assert gains[1] > gains[0]
    assert gains[1] > 0.05
    assert abs(gains[0]) < 0.05  # observing an observed point again teaches (almost) nothing
    regret = minimum_regret_search(gp, reps, np.vstack([at_data, uncertain]), np.random.default_rng(1))
    assert regret[1] > regret[0]
    # the functional form gives the same numbers for the same generator state
    np.testing.assert_allclose(
        entropy_search(gp, reps, np.vstack([at_data, uncertain]), np.random.default_rng(5), n_samples=512),
        RepresenterModel(gp, reps, np.random.default_rng(5), n_samples=512).information_gain(np.vstack([at_data, uncertain])))


# ---------------------------------------------------------------------------- the optimizer
def run_branin(acquisition, n_evals=30, seed=0, **kwargs):
    opt = BayesianOptimizer(BRANIN_BOUNDS, acquisition, rng=np.random.default_rng(seed), budget=n_evals, **kwargs)
    while not opt.stop():
        x = opt.ask()
        assert x.shape == (1, 2)
        assert np.all(x >= BRANIN_BOUNDS[:, 0]) and np.all(x <= BRANIN_BOUNDS[:, 1])
        opt.tell(x, -branin(x))
    return opt


@pytest.mark.parametrize("acquisition", ["ucb", "ei", "es", "mrs"])
def test_bayesopt_solves_branin_in_30_evaluations(acquisition):
    opt = run_branin(acquisition)
    regret = branin(opt.recommend())[0] - BRANIN_MIN
    assert regret < 0.05, f"{acquisition}: regret {regret:.4f} after 30 evaluations"
    assert len(opt.y) == 30


def test_failed_episode_is_penalised_and_search_goes_on():
    opt = BayesianOptimizer(BRANIN_BOUNDS, "es", rng=np.random.default_rng(0), n_initial=3, n_samples=64)
    opt.tell(opt.ask(), np.array([np.nan]))  # a failed first episode is kept but never the best
    assert opt.failed.tolist() == [True] and np.isfinite(opt.y).all()
    assert opt.best[1] == -np.inf
    opt = BayesianOptimizer(BRANIN_BOUNDS, "es", rng=np.random.default_rng(0), n_initial=3, n_samples=64)
    for reward in (-10.0, -20.0, np.nan, -5.0, np.inf):
        opt.tell(opt.ask(), np.array([reward]))
    assert np.isfinite(opt.y).all()
    assert opt.failed.tolist() == [False, False, True, False, True]
    assert opt.y[2] < -20.0 and opt.y[4] < -20.0
    assert np.isfinite(opt.ask()).all()
    assert opt.best[1] == -5.0


def test_bayesopt_rejects_bad_input():
    with pytest.raises(ValueError, match="acquisition"):
        BayesianOptimizer(BRANIN_BOUNDS, "pi")
    opt = BayesianOptimizer(BRANIN_BOUNDS, "ucb", rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="shape"):
        opt.tell(np.zeros((1, 3)), np.zeros(1))
    with pytest.raises(ValueError, match="NaN"):
        opt.tell(np.array([[np.nan, 1.0]]), np.zeros(1))


@pytest.mark.parametrize("acquisition", ["ei", "es"])
def test_bayesopt_state_roundtrip_continues_identically(tmp_path, acquisition):
    opt = run_branin(acquisition, n_evals=8, n_samples=64)
    save_state(opt.state_dict(), tmp_path / "bo")
    restored = BayesianOptimizer.from_state(load_state(tmp_path / "bo"))
    for _ in range(2):
        a, b = opt.ask(), restored.ask()
        np.testing.assert_allclose(a, b)
        opt.tell(a, -branin(a))
        restored.tell(b, -branin(b))
    np.testing.assert_allclose(opt.recommend(), restored.recommend())


@pytest.mark.slow
@pytest.mark.parametrize("acquisition", ["ucb", "ei", "es", "mrs"])
def test_bayesopt_branin_over_seeds(acquisition):
    regrets = [branin(run_branin(acquisition, seed=seed).recommend())[0] - BRANIN_MIN for seed in range(5)]
    assert np.median(regrets) < 0.01 and max(regrets) < 0.1, regrets


def test_bayesopt_runs_and_resumes_in_the_search_loop(tmp_path):
    from besdrake.search.loop import run_search

    def make():
        return BayesianOptimizer(BRANIN_BOUNDS, "ei", rng=np.random.default_rng(3), n_initial=4)

    def evaluate(x):
        return -float(branin(x)[0])

    full = run_search(make(), evaluate_episode=evaluate, n_evaluations=10)
    run_search(make(), evaluate_episode=evaluate, n_evaluations=10, out_dir=tmp_path,
               callback=lambda info: info.n_evaluations >= 6)
    resumed = run_search(make(), evaluate_episode=evaluate, n_evaluations=10, out_dir=tmp_path)
    assert resumed.resumed and resumed.n_evaluations == 10
    np.testing.assert_array_equal(resumed.params, full.params)
    assert resumed.best_reward == full.best_reward == max(full.rewards)
