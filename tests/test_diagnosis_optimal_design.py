"""Model-based experiment design: the D-optimal log tells causes apart that a random one confounds.

Default: the greedy choice on made-up information blocks (it breaks a collinearity a stronger plan would keep), the
pool split (fixed plans kept with their multiplicity, candidates deduplicated), and a designed throwing log on made-up
sensitivities (its size, repeats and fixed plans as requested, within the robot's limits, cached). Slow
(``--runslow``): the registry's real sensitivities on a small pool raise the parameters' conditional information.
"""

from __future__ import annotations

import numpy as np
import pytest

from besdrake.diagnosis import optimal_design as od
from besdrake.plan import MotionPlan
from besdrake.robot import load_robot
from besdrake.transfer.measurement import plan_hash

COMPI = load_robot("compi")


def _block(*j):
    v = np.asarray(j, dtype=float)
    return np.outer(v, v)


def test_the_greedy_choice_breaks_a_collinearity_a_stronger_plan_keeps():
    # Two parameters the logged plans move alike; candidate 0 moves them alike three times as strongly, candidate 1
    # moves them against each other, with a quarter of its signal: only candidate 1 tells them apart.
    base = od.PRIOR_PRECISION * np.eye(2) + 10 * _block(1, 1)
    blocks = np.array([_block(3, 3), _block(1.5, -1.5), _block(0.5, 0.5)])
    assert od.greedy_d_optimal(blocks, base, 1) == [1]
    assert od.greedy_d_optimal(blocks, base, 1, allowed=[0, 2]) == [0]
    M = od.information(blocks, {1: 1}, base)
    assert np.all(od.conditional_information(M) > od.conditional_information(od.information(blocks, {0: 1}, base)))


def test_blocks_count_only_the_recorded_features():
    per_plan = np.array([[[1.0, 0.0, 2.0], [0.0, 1.0, 0.0]]])  # one plan, two parameters, three features
    assert np.allclose(od.blocks_of(per_plan)[0], [[5.0, 0.0], [0.0, 1.0]])
    assert np.allclose(od.blocks_of(per_plan, [2])[0], [[4.0, 0.0], [0.0, 0.0]])


def test_the_greedy_choice_beats_random_choices_of_the_same_size():
    rng = np.random.default_rng(3)
    wins = 0
    for _ in range(20):
        J = rng.normal(size=(30, 4, 6)) * rng.uniform(0.1, 2.0, size=(30, 1, 1))
        blocks = np.einsum("npf,nqf->npq", J, J)
        base = od.PRIOR_PRECISION * np.eye(4)
        greedy = np.linalg.slogdet(od.information(blocks, {i: 1 for i in od.greedy_d_optimal(blocks, base, 5)}, base))[1]
        rand = [np.linalg.slogdet(od.information(blocks, {int(i): 1 for i in rng.choice(30, 5, replace=False)}, base))[1] for _ in range(20)]
        wins += greedy >= max(rand)
    assert wins >= 18, wins


def _plan(v: float, name: str) -> MotionPlan:
    t = np.linspace(0.0, 1.0, 11)
    return MotionPlan(t, np.outer(t, np.full(6, v)), None, {"name": name})


def test_the_pool_keeps_fixed_plans_with_their_multiplicity_and_deduplicates_candidates():
    probe = _plan(9.0, "probe")
    a, b, c = _plan(1.0, "a"), _plan(2.0, "b"), _plan(3.0, "c")
    b2 = _plan(2.0, "b")  # the same trajectory in another design
    designs = [[a, probe, b, a, probe], [b2, probe, c, probe, c], [c, probe, probe]]
    candidates, fixed, reference, repeats = od._split_pool(designs)
    assert [(p.meta["name"], k) for p, k in fixed] == [("probe", 2)]
    assert [plan_hash(p) for p in candidates] == [plan_hash(a), plan_hash(b), plan_hash(c)]
    assert reference == [0, 1] and repeats == [0]


@pytest.fixture
def fake_sensitivities(monkeypatch, tmp_path):
    """Made-up sensitivities (a fixed random block per plan, from its hash), counted, cached under ``tmp_path``."""
    monkeypatch.setenv("BESDRAKE_CACHE", str(tmp_path))
    calls = []

    def fake(executor, effects, plans, model=None):
        calls.append(len(plans))
        keys = [f"e{i}.p" for i in range(5)]
        cols = [np.random.default_rng(int(plan_hash(p)[:8], 16)).normal(size=(5, 7)) for p in plans]
        return keys, np.concatenate(cols, axis=1)

    monkeypatch.setattr(od, "scaled_sensitivities", fake)
    return calls


def test_a_designed_log_has_the_requested_size_repeats_and_fixed_plans(fake_sensitivities, tmp_path):
    from besdrake.tasks.throwing.diagnosis.design import plan_limits_exceeded

    d = od.optimal_plans(25, 8, seed=4, executor=object(), design_options={"probes": 2, "sideways": 5})
    hashes = [plan_hash(p) for p in d.plans]
    counts = {h: hashes.count(h) for h in hashes}
    assert len(d.plans) == 25 and len(counts) == 25 - 8
    probes = [p for p in d.plans if p.meta["name"].startswith("probe")]
    assert len(probes) == 4 and all(counts[plan_hash(p)] == 2 for p in probes)
    assert not any(plan_limits_exceeded(p, COMPI.limits) for p in d.plans)
    assert d.log_det > d.reference_log_det and d.median_gain() > 1.0
    # another seed chooses from another share of the pool; the pool's sensitivities come from the cache
    d2 = od.optimal_plans(25, 8, seed=5, executor=object(), design_options={"probes": 2, "sideways": 5})
    assert {plan_hash(p) for p in d2.plans} != set(hashes)
    assert len(fake_sensitivities) == 1 and len(list((tmp_path / "design").glob("*.npz"))) == 1


def test_an_impossible_request_is_a_value_error(fake_sensitivities):
    pool = od.design_pool(6, 0, executor=object(), design_options={"probes": 0, "sideways": 0})
    with pytest.raises(ValueError, match="cannot choose"):
        od.optimal_plans(6, 4, pool=pool)  # 2 distinct plans cannot give 4 repeats


@pytest.mark.slow
def test_real_sensitivities_raise_the_conditional_information(monkeypatch, tmp_path):
    monkeypatch.setenv("BESDRAKE_CACHE", str(tmp_path))
    monkeypatch.setattr(od, "POOL_DESIGNS", 4)
    monkeypatch.setattr(od, "CANDIDATE_SHARE", 1.0)  # a pool this small: choose from all of it (half of it can lose)
    d = od.optimal_plans(25, 8, seed=0, design_options={"probes": 2, "sideways": 5})
    gains = np.array([g for g in d.gain.values() if np.isfinite(g)])
    assert d.log_det > d.reference_log_det
    assert np.median(gains) > 1.1 and np.mean(gains >= 0.95) > 0.8, d.gain


def test_cli_writes_the_optimal_design_the_lab_runner_reads(fake_sensitivities, tmp_path, capsys):
    from besdrake.cli import main
    from besdrake.commands.lab_run import load_plans

    assert main(["diagnose", "--design", str(tmp_path / "plans"), "--optimal", "--throws", "12", "--repeats", "4"]) == 0
    plans = load_plans(tmp_path / "plans")
    assert len(plans) == 12 and len({plan_hash(p) for p in plans}) == 8
    assert "D-optimal design" in capsys.readouterr().out
    assert main(["diagnose", "--design", str(tmp_path / "throws"), "--optimal", "--throws", "12", "--repeats", "6", "--probes", "0"]) == 0
    assert main(["diagnose", "--design", str(tmp_path / "small"), "--optimal", "--throws", "6", "--repeats", "3", "--probes", "0",
                 "--sideways", "0"]) == 0
    capsys.readouterr()
    assert main(["diagnose", "--design", str(tmp_path / "bad"), "--optimal", "--throws", "12", "--repeats", "9"]) == 2
    assert "besdrake: error:" in capsys.readouterr().err


def test_cli_designs_another_tasks_experiment_too(fake_sensitivities, tmp_path):
    from besdrake.cli import main
    from besdrake.commands.lab_run import load_plans

    assert main(["diagnose", "--design", str(tmp_path / "picks"), "--optimal", "--scenario", "pick_and_place", "--throws", "10",
                 "--repeats", "4"]) == 0
    plans = load_plans(tmp_path / "picks")
    assert len(plans) == 10 and len({plan_hash(p) for p in plans}) == 6
