import numpy as np

from besdrake.search.base import load_state, rng_from_state, rng_state, sanitize_rewards, save_state


def test_sanitize_rewards_replaces_non_finite_with_penalised_worst():
    rewards, failed = sanitize_rewards(np.array([1.0, np.nan, -2.0, np.inf]), worst_seen=-1.0)
    assert failed.tolist() == [False, True, False, True]
    assert rewards[1] == rewards[3] == -3.0
    assert np.isfinite(rewards).all()


def test_state_roundtrip_keeps_arrays_and_rng(tmp_path):
    rng = np.random.default_rng(3)
    rng.normal(size=5)
    state = {"mean": np.arange(3.0), "sigma": 0.5, "nested": {"cov": np.eye(2)}, "rng": rng_state(rng)}
    save_state(state, tmp_path / "opt")
    loaded = load_state(tmp_path / "opt")
    np.testing.assert_array_equal(loaded["mean"], state["mean"])
    np.testing.assert_array_equal(loaded["nested"]["cov"], np.eye(2))
    assert loaded["sigma"] == 0.5
    assert rng_from_state(loaded["rng"]).normal() == rng.normal()
