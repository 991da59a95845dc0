"""BO-CPS (UCB and contextual entropy search) and ACES on a nonlinear contextual problem."""

import numpy as np
import pytest

from besdrake.search.aces import ACES
from besdrake.search.base import load_state, rng_state, save_state
from besdrake.search.bocps import BOCPS

CONTEXT_BOUNDS = np.array([[-1.0, 1.0], [-1.0, 1.0]])
PARAM_BOUNDS = np.array([[-1.0, 1.0], [-1.0, 1.0]])
TEST_CONTEXTS = np.array([[a, b] for a in (-0.7, -0.2, 0.2, 0.7) for b in (-0.7, -0.2, 0.2, 0.7)])


def optimal_params(s):
    """A nonlinear upper-level policy theta*(s) that BO-CPS must learn."""
    return np.array([0.5 * s[0] + 0.3 * s[1] ** 2, -0.4 * s[1] + 0.2 * np.sin(2 * s[0])])


def reward(s, theta):
    return -float(np.sum((theta - optimal_params(s)) ** 2))


def policy_error(opt):
    return float(np.mean([np.linalg.norm(opt.policy(s) - optimal_params(s)) for s in TEST_CONTEXTS]))


def train(opt, n_episodes, rng=None):
    for _ in range(n_episodes):
        s = opt.select_context(CONTEXT_BOUNDS)
        assert np.all(s >= CONTEXT_BOUNDS[:, 0]) and np.all(s <= CONTEXT_BOUNDS[:, 1])
        theta = opt.ask(s)
        assert theta.shape == (2,)
        assert np.all(theta >= PARAM_BOUNDS[:, 0]) and np.all(theta <= PARAM_BOUNDS[:, 1])
        opt.tell(s, theta, reward(s, theta))
    return opt


@pytest.mark.parametrize("acquisition, n_episodes, tolerance", [("ucb", 40, 0.12), ("es", 40, 0.08)])
def test_bocps_learns_contextual_policy(acquisition, n_episodes, tolerance):
    opt = train(BOCPS(CONTEXT_BOUNDS, PARAM_BOUNDS, acquisition, rng=np.random.default_rng(0)), n_episodes)
    untrained = float(np.mean([np.linalg.norm(optimal_params(s)) for s in TEST_CONTEXTS]))  # policy = centre
    err = policy_error(opt)
    assert err < tolerance, f"{acquisition}: mean policy error {err:.3f} after {n_episodes} episodes"
    assert err < 0.25 * untrained


def test_aces_selects_informative_contexts_and_learns():
    opt = ACES(CONTEXT_BOUNDS, PARAM_BOUNDS, rng=np.random.default_rng(0), n_samples=128, n_context_candidates=20)
    train(opt, 30)
    assert policy_error(opt) < 0.1
    # the pair chosen by select_context is what ask returns for that context
    s = opt.select_context(CONTEXT_BOUNDS)
    theta = opt.ask(s)
    assert opt._pending is None
    assert not np.allclose(theta, opt.ask(s))  # a second ask falls back to BO-CPS/ES
    # restricted bounds are respected
    sub = np.array([[0.5, 1.0], [-1.0, -0.5]])
    s = opt.select_context(sub)
    assert np.all(s >= sub[:, 0]) and np.all(s <= sub[:, 1])


def test_policy_is_deterministic_and_consumes_no_randomness():
    opt = train(BOCPS(CONTEXT_BOUNDS, PARAM_BOUNDS, "ucb", rng=np.random.default_rng(1)), 12)
    before = rng_state(opt.rng)
    a = opt.policy(np.array([0.3, -0.4]))
    b = opt.policy(np.array([0.3, -0.4]))
    np.testing.assert_array_equal(a, b)
    assert rng_state(opt.rng) == before


def test_failed_episode_is_penalised_and_learning_goes_on():
    opt = BOCPS(CONTEXT_BOUNDS, PARAM_BOUNDS, "es", rng=np.random.default_rng(0), n_initial=3, n_samples=64)
    for r in (-0.5, -1.0, np.nan, -0.2):
        s = opt.select_context(CONTEXT_BOUNDS)
        opt.tell(s, opt.ask(s), r)
    assert opt.failed.tolist() == [False, False, True, False]
    assert np.isfinite(opt.y).all() and opt.y[2] < -1.0
    assert np.isfinite(opt.ask(np.zeros(2))).all()


def test_bocps_rejects_bad_input():
    with pytest.raises(ValueError, match="acquisition"):
        BOCPS(CONTEXT_BOUNDS, PARAM_BOUNDS, "ei")
    with pytest.raises(ValueError, match="context_bounds"):
        BOCPS(np.array([[0.0, np.nan]]), PARAM_BOUNDS)
    opt = BOCPS(CONTEXT_BOUNDS, PARAM_BOUNDS, "ucb", rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="context"):
        opt.ask(np.zeros(3))
    with pytest.raises(ValueError, match="finite"):
        opt.policy(np.array([np.inf, 0.0]))
    with pytest.raises(ValueError, match="params"):
        opt.tell(np.zeros(2), np.zeros(1), 0.0)
    with pytest.raises(ValueError, match="reward"):
        opt.tell(np.zeros(2), np.zeros(2), np.array([1.0, 2.0]))
    assert opt.y.size == 0  # nothing half-recorded


@pytest.mark.parametrize("cls, kwargs", [(BOCPS, {"acquisition": "es"}), (ACES, {})])
def test_state_roundtrip_gives_same_policy_and_continues_identically(tmp_path, cls, kwargs):
    opt = train(cls(CONTEXT_BOUNDS, PARAM_BOUNDS, rng=np.random.default_rng(2), n_samples=64, **kwargs), 10)
    s = opt.select_context(CONTEXT_BOUNDS)  # ACES: leaves a pending pair in the state
    save_state(opt.state_dict(), tmp_path / "template")
    restored = cls.from_state(load_state(tmp_path / "template"))
    for c in TEST_CONTEXTS[:4]:
        np.testing.assert_allclose(restored.policy(c), opt.policy(c), rtol=1e-9, atol=1e-12)
    for _ in range(2):
        a, b = opt.ask(s), restored.ask(s)
        np.testing.assert_allclose(a, b)
        opt.tell(s, a, reward(s, a))
        restored.tell(s, b, reward(s, b))
        s = opt.select_context(CONTEXT_BOUNDS)
        np.testing.assert_allclose(restored.select_context(CONTEXT_BOUNDS), s)


@pytest.mark.slow
@pytest.mark.parametrize("acquisition", ["ucb", "es", "aces"])
def test_bocps_over_seeds_60_episodes(acquisition):
    errors = []
    for seed in range(3):
        rng = np.random.default_rng(seed)
        opt = ACES(CONTEXT_BOUNDS, PARAM_BOUNDS, rng=rng) if acquisition == "aces" else BOCPS(
            CONTEXT_BOUNDS, PARAM_BOUNDS, acquisition, rng=rng)
        errors.append(policy_error(train(opt, 60)))
    assert np.median(errors) < (0.06 if acquisition == "ucb" else 0.04), errors


def test_bocps_runs_and_resumes_in_the_search_loop(tmp_path):
    """Driven by the shared loop: a crashed evaluation is a failed episode, and a resumed run
    continues exactly like an uninterrupted one (the loop checks the re-asked parameters)."""
    from besdrake.search.loop import run_contextual_search

    def evaluate(s, theta):
        if len(calls) == 5:
            calls.append(1)
            raise RuntimeError("simulated rollout crash")
        calls.append(1)
        return reward(s, theta)

    def make():
        return BOCPS(CONTEXT_BOUNDS, PARAM_BOUNDS, "es", rng=np.random.default_rng(4), n_initial=4, n_samples=64)

    calls: list[int] = []
    full = run_contextual_search(make(), evaluate, 10, CONTEXT_BOUNDS)
    calls = []
    run_contextual_search(make(), evaluate, 10, CONTEXT_BOUNDS, tmp_path / "run",
                          callback=lambda info: info.n_evaluations >= 7)
    resumed = run_contextual_search(make(), evaluate, 10, CONTEXT_BOUNDS, tmp_path / "run")
    assert resumed.resumed and resumed.n_evaluations == full.n_evaluations == 10
    np.testing.assert_array_equal(resumed.params, full.params)
    np.testing.assert_array_equal(resumed.contexts, full.contexts)
    assert resumed.failed.tolist() == full.failed.tolist() == [i == 5 for i in range(10)]
    restored = BOCPS.from_state(load_state(tmp_path / "run" / "optimizer")["optimizer"])
    assert restored.failed.tolist() == [i == 5 for i in range(10)]
    np.testing.assert_allclose(restored.policy(TEST_CONTEXTS[0]), full.optimizer.policy(TEST_CONTEXTS[0]))


def test_length_scale_min_bounds_the_fit_and_is_kept_in_the_state(tmp_path):
    opt = train(BOCPS(CONTEXT_BOUNDS, PARAM_BOUNDS, "ucb", rng=np.random.default_rng(4), length_scale_min=0.2), 12)
    opt.policy(TEST_CONTEXTS[0])  # fits the GP
    assert np.all(opt.gp.length_scales >= 0.2 - 1e-9)
    save_state(opt.state_dict(), tmp_path / "opt")
    state = load_state(tmp_path / "opt")
    assert BOCPS.from_state(state).length_scale_min == 0.2
    del state["settings"]["length_scale_min"]  # a state written before the setting existed
    assert BOCPS.from_state(state).length_scale_min == 0.01
    for bad in (0.0, -1.0, np.nan, 10.0):
        with pytest.raises(ValueError, match="length_scale_min"):
            BOCPS(CONTEXT_BOUNDS, PARAM_BOUNDS, length_scale_min=bad)
