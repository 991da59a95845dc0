"""Refinement: the dropped-ball penalty, the meta-parameter stage (StagedCMAES, meta_basis) and its resume."""

from __future__ import annotations

import numpy as np
import pytest

from besdrake.search.base import load_state, save_state
from besdrake.search.cmaes import StagedCMAES
from besdrake.search.refinement import (
    META_OFFSET_UNIT,
    RefinementError,
    RefinementProblem,
    meta_basis,
    refine,
)
from besdrake.tasks.throwing.template_base import fitted_default_throw
from besdrake.tasks.throwing.reward import DROPPED_PENALTY, ThrowReward
from tests.test_refinement import StandIn, outcome


from besdrake.robot import load_robot

COMPI = load_robot("compi")


@pytest.fixture(scope="module")
def base():
    return fitted_default_throw()


def test_dropped_ball_scores_below_the_same_touchdown_thrown(base):
    from besdrake.imitation import DMPParameterization

    plan = DMPParameterization(base).motion_plan(DMPParameterization(base).to_vector(), dt=0.01)
    rew = ThrowReward(dropped_penalty=1.0)
    thrown = rew(plan, outcome([1.5, 0.0]), COMPI.limits)
    dropped = rew(plan, outcome([1.5, 0.0], dropped_early=True), COMPI.limits)
    assert dropped.distance == thrown.distance == pytest.approx(0.5)
    assert dropped.reward == pytest.approx(thrown.reward - 1.0)
    # a dropped ball never beats a real throw that lands farther from the target by less than the penalty
    worse_throw = rew(plan, outcome([1.5 - 0.9, 0.0]), COMPI.limits)
    assert worse_throw.reward > dropped.reward
    default = ThrowReward()(plan, outcome([1.5, 0.0], dropped_early=True), COMPI.limits)
    assert default.reward == pytest.approx(thrown.reward - DROPPED_PENALTY)
    with pytest.raises(RefinementError):
        ThrowReward(dropped_penalty=-1.0)
    assert ThrowReward.from_dict(ThrowReward(dropped_penalty=0.3).to_dict()).dropped_penalty == 0.3


def test_meta_basis_shifts_start_and_goal_together(base):
    problem = RefinementProblem(COMPI, base)
    B = meta_basis(problem)
    n = base.n_dims
    assert B.shape == (problem.n_params, 2 * n + 1)
    theta0 = problem.theta(np.zeros(problem.n_params))
    for j in range(n):
        d = problem.theta(0.1 * B[:, j]) - theta0  # small step: inside the bounds
        assert d[j] == pytest.approx(0.1 * META_OFFSET_UNIT) and d[n + j] == pytest.approx(0.1 * META_OFFSET_UNIT)
        assert np.count_nonzero(np.abs(d) > 1e-12) == 2
    d = problem.theta(0.1 * B[:, -1]) - theta0
    assert np.flatnonzero(np.abs(d) > 1e-12).tolist() == [problem.n_params - 1]
    with pytest.raises(RefinementError):
        meta_basis(problem, offset_unit=0.0)


def sphere(X, target):
    return -np.sum((np.atleast_2d(X) - target) ** 2, axis=1)


def test_staged_cmaes_searches_the_subspace_first_then_everything():
    n = 8
    rng = np.random.default_rng(0)
    basis = np.zeros((n, 2))
    basis[0, 0] = basis[1, 0] = 1.0  # a joint direction
    basis[2, 1] = 1.0
    target = np.array([2.0, 2.0, -1.0, 0.3, -0.2, 0.1, 0.0, 0.2])
    opt = StagedCMAES(np.zeros(n), basis, 1.0, 0.3, rng, subspace_evaluations=200, popsize_subspace=6, popsize=8,
                      bounds=np.tile([-5.0, 5.0], (n, 1)))
    seen_stage1 = 0
    while opt.stage == 1:
        X = opt.ask()
        assert X.shape == (6, n)
        assert np.allclose(X[:, 0], X[:, 1]) and np.allclose(X[:, 3:], 0.0)  # inside the subspace
        opt.tell(X, sphere(X, target))
        seen_stage1 += len(X)
    assert 200 <= seen_stage1 < 206
    best1 = opt.best[1]
    assert best1 > sphere(np.zeros(n), target)[0] + 5.0  # the subspace stage did most of the work
    for _ in range(150):
        X = opt.ask()
        assert X.shape == (8, n)
        opt.tell(X, sphere(X, target))
    assert opt.best[1] > -0.01 and opt.best[1] > best1


@pytest.mark.parametrize("generations", [3, 12])  # resume in stage 1 and in stage 2
def test_staged_cmaes_resumes_with_the_same_candidates(tmp_path, generations):
    n = 5
    basis = np.eye(n)[:, :2]
    target = np.linspace(-1, 1, n)
    make = lambda: StagedCMAES(np.zeros(n), basis, 1.0, 0.5, np.random.default_rng(7), subspace_evaluations=30,
                               popsize_subspace=5, popsize=6, bounds=np.tile([-3.0, 3.0], (n, 1)))
    a = make()
    for _ in range(generations):
        X = a.ask()
        a.tell(X, sphere(X, target))
    save_state(a.state_dict(), tmp_path / "state")
    b = StagedCMAES.from_state(load_state(tmp_path / "state"))
    assert b.stage == a.stage == (1 if generations == 3 else 2)
    for _ in range(4):
        Xa, Xb = a.ask(), b.ask()
        np.testing.assert_array_equal(Xa, Xb)
        a.tell(Xa, sphere(Xa, target))
        b.tell(Xb, sphere(Xb, target))
    assert a.best[1] == b.best[1]


def test_staged_cmaes_rejects_bad_input():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError):
        StagedCMAES(np.zeros(3), np.zeros((2, 1)), 1.0, 1.0, rng, subspace_evaluations=10)
    with pytest.raises(ValueError):
        StagedCMAES(np.zeros(3), np.ones((3, 1)), 0.0, 1.0, rng, subspace_evaluations=10)
    with pytest.raises(ValueError):
        StagedCMAES(np.zeros(3), np.ones((3, 1)), 1.0, 1.0, rng, subspace_evaluations=-1)
    opt = StagedCMAES(np.zeros(3), np.ones((3, 1)), 1.0, 1.0, rng, subspace_evaluations=10)
    X = opt.ask()
    with pytest.raises(ValueError):
        opt.tell(X + 1.0, np.zeros(len(X)))


def test_refine_with_meta_stage_succeeds_and_resumes(base, tmp_path):
    problem = RefinementProblem(COMPI, base)
    result = refine(problem, StandIn(), n_episodes=1500, seed=1, meta_episodes=100)
    assert result.success, result.summary()
    first = refine(problem, StandIn(), n_episodes=24, seed=3, popsize=8, out_dir=tmp_path, stop_on_success=False, meta_episodes=16)
    ex = StandIn()
    again = refine(RefinementProblem(COMPI, base), ex, n_episodes=48, seed=3, popsize=8, out_dir=tmp_path, stop_on_success=False, meta_episodes=16)
    assert first.n_episodes == 24 and again.resumed and again.n_episodes == 48 and ex.calls == 24
    with pytest.raises(RefinementError, match="another refinement"):
        refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=60, seed=3, popsize=8, out_dir=tmp_path, meta_episodes=32)
    with pytest.raises(RefinementError):
        refine(problem, StandIn(), n_episodes=10, meta_episodes=-1)


def test_refine_cli_meta_stage_and_dropped_penalty(base, tmp_path):
    import json

    from besdrake.cli import main
    from besdrake.imitation import save_dmp

    slow = base.copy()
    slow.execution_time = 2.3
    dmp_file = save_dmp(slow, tmp_path / "throw.dmp.json")
    out = tmp_path / "run"
    argv = ["refine", str(dmp_file), "--out", str(out), "--episodes", "8", "--popsize", "4", "--backend", "serial", "--quiet",
            "--json", "--no-figures", "--meta-episodes", "4", "--dropped-penalty", "0.5"]
    assert main(argv) == 0
    problem = json.loads((out / "run0" / "problem.json").read_text())
    assert problem["meta_episodes"] == 4 and problem["reward"]["dropped_penalty"] == 0.5
    state = json.loads((out / "run0" / "optimizer.json").read_text())
    assert state["optimizer"]["type"] == "StagedCMAES" and state["optimizer"]["stage"] == 2
    assert main(argv[:-4] + ["--meta-episodes", "-1"]) == 2


def test_scaling_max_execution_time_bounds_the_time(base):
    from besdrake.search.refinement import MAX_EXECUTION_TIME, MIN_EXECUTION_TIME, ParameterScaling

    s = ParameterScaling.for_dmp(base, COMPI.position_limits, max_execution_time=1.2)
    assert s.bounds[-1].tolist() == [MIN_EXECUTION_TIME, 1.2]
    assert s.to_theta(np.full(s.theta0.size, 50.0))[-1] == pytest.approx(1.2)
    assert ParameterScaling.for_dmp(base, COMPI.position_limits).bounds[-1, 1] == MAX_EXECUTION_TIME
    for bad in (MIN_EXECUTION_TIME, MAX_EXECUTION_TIME + 1.0, float("nan")):
        with pytest.raises(RefinementError):
            ParameterScaling.for_dmp(base, COMPI.position_limits, max_execution_time=bad)


@pytest.mark.slow
def test_real_simulation_refines_a_slow_throw_to_success(base):
    """A few hundred episodes of the default search on the simulation: the fitted default throw slowed
    down (lands ~0.8 m short) is refined into a throw within 0.1 m of the target and every limit."""
    from besdrake.sim import make_executor

    slow = base.copy()
    slow.execution_time = 2.3
    problem = RefinementProblem(COMPI, slow)
    with make_executor("serial") as ex:
        result = refine(problem, ex, n_episodes=400, seed=0)
    assert result.success, result.summary()
    assert result.penalties[result.episodes_to_success - 1] == 0.0
