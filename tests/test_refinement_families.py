"""Scouts and races from the imitated throws themselves: CMA-ES with fixed coordinates, RefinementProblem families
(another imitated throw keeps its goal velocity and its own weight bounds) and family_run."""

from __future__ import annotations

import numpy as np
import pytest

from besdrake.search.base import load_state, save_state
from besdrake.search.cmaes import CMAES, StagnationRestartCMAES
from besdrake.search.refinement import (ParameterScaling, RefinementError, RefinementProblem, family_run, rank_starts, refine, restart_points,
                                        run_start_order)
from besdrake.tasks.throwing.template_base import fitted_default_throw
from tests.test_refinement import COMPI, outcome


@pytest.fixture(scope="module")
def base():
    return fitted_default_throw()


@pytest.fixture(scope="module")
def other(base):
    """Another imitated throw: its own goal velocity and acceleration, and one weight far beyond the base's bounds."""
    d = base.copy()
    d.goal_velocity = d.goal_velocity + np.array([0.0, 0.6, -0.4, 0.0, 0.5, 0.0])
    d.goal_acceleration = d.goal_acceleration + 2.0
    w = d.weights.copy()
    w[2, 1] += 80.0 * ParameterScaling.for_dmp(base, COMPI.position_limits).scale[2 * 6 + 2 * 6 + 1]
    d.weights = w
    return d


class Release:
    """Stand-in simulation that sees the end of the swing: x = joint-2 goal + its final velocity / 2 + 1 m."""

    def evaluate(self, plans):
        return [outcome([p.q[-1, 1] + 0.5 * p.qd[-1, 1] + 1.0, p.q[-1, 0]]) for p in plans]


def _problems(base, other):
    return [RefinementProblem(COMPI, d, retime=False) for d in (base, other)]


def test_a_family_start_plays_the_imitated_throw_itself_where_a_hybrid_does_not(base, other):
    p0, p1 = _problems(base, other)
    fam = p0.with_families([p1])
    assert fam.n_params == p0.n_params + 1 and fam.fixed == (p0.n_params,)
    assert np.allclose(fam.x_bounds[-1], [-0.5, 1.5])
    own, own0 = p1.plan(np.zeros(p1.n_params)), p0.plan(np.zeros(p0.n_params))
    x1 = fam.family_start(1, p1)
    assert np.allclose(fam.plan(x1).q, own.q) and np.allclose(fam.plan(x1).qd, own.qd)
    assert np.allclose(fam.plan(fam.family_start(0)).q, own0.q)  # family 0: the template, as before
    assert np.allclose(fam.dmp(x1).goal_velocity, other.goal_velocity)
    # the old start point: the other's parameters in the base's DMP (its goal velocity, its weight bounds)
    hybrid = p0.plan(restart_points(p0, [p1])[0])
    assert np.abs(hybrid.qd[-1] - own.qd[-1]).max() > 0.3


def test_each_family_keeps_its_own_follow_through_and_retiming(base):
    fast = base.copy()  # another throw, faster: its retiming and its follow-through's braking are its own
    fast.execution_time = 0.8 * base.execution_time
    fast.goal_velocity = fast.goal_velocity + 0.3
    p0 = RefinementProblem(COMPI, base, follow_through=0.5)
    p1 = RefinementProblem(COMPI, fast, follow_through=0.8)
    fam = p0.with_families([p1])
    assert fam.phases == [0.5, 0.8]
    x1 = fam.family_start(1, p1)
    own = p1.plan(np.zeros(p1.n_params))
    assert np.allclose(fam.plan(x1).t, own.t) and np.allclose(fam.plan(x1).q, own.q)
    assert np.allclose(fam.theta(x1), p1.theta(np.zeros(p1.n_params)))
    again = RefinementProblem.from_description(fam.describe())
    assert again.phases == [0.5, 0.8] and np.allclose(again.plan(x1).q, own.q)
    with pytest.raises(RefinementError, match="one phase per family"):
        RefinementProblem(COMPI, base, families=[fast], family_follow_through=[0.5, 0.6])


def test_covering_bounds_hold_every_family_and_keep_the_units(base, other):
    p0, p1 = _problems(base, other)
    cov = p0.scaling.covering([p1.scaling])
    assert np.all(cov.bounds[:, 0] <= np.minimum(p0.scaling.bounds[:, 0], p1.scaling.bounds[:, 0]))
    assert np.all(cov.bounds[:, 1] >= np.maximum(p0.scaling.bounds[:, 1], p1.scaling.bounds[:, 1]))
    assert np.array_equal(cov.theta0, p0.scaling.theta0) and np.array_equal(cov.scale, p0.scaling.scale)
    assert p0.with_families([]) is p0


def test_a_bad_family_coordinate_is_a_failed_episode_and_the_record_rebuilds_the_families(base, other):
    p0, p1 = _problems(base, other)
    fam = p0.with_families([p1])
    x = fam.family_start(1, p1)
    bad = [x.copy() for _ in range(2)]
    bad[0][-1], bad[1][-1] = 2.0, np.nan
    recs = fam.evaluate(np.array(bad), Release())
    assert all(np.isnan(r.reward) and "failed" in r.flags for r in recs)
    assert "family" in recs[0].message and "NaN" in recs[1].message
    again = RefinementProblem.from_description(fam.describe())
    assert again.n_params == fam.n_params and np.allclose(again.plan(x).qd, fam.plan(x).qd)


def test_family_run_holds_the_scouts_and_races_throws_in_order(base, other):
    third = base.copy()
    third.goal = third.goal + 0.05
    problems = [RefinementProblem(COMPI, d, retime=False) for d in (base, other, third)]
    order = [2, 0, 1]
    run = family_run(problems, order, group=0, races=2, n=2)
    assert run.index == 2 and run.starts.shape == (2, 50) and run.next_starts.shape == (2, 50)
    assert run.starts[:, -1].tolist() == [0.0, 1.0] and run.next_starts[:, -1].tolist() == [2.0, 0.0]  # wraps around
    for x, i in zip([*run.starts, run.next_starts[0]], [2, 0, 1]):
        assert np.allclose(run.problem.plan(x).qd, problems[i].plan(np.zeros(49)).qd)
    later = family_run(problems, order, group=1, n=2)
    assert later.index == run_start_order(order, 1, 2)[0] and later.next_starts is None
    one = family_run(problems, order, group=0, n=1)
    assert one.starts is None and one.problem is problems[2] and one.problem.n_params == 49


def test_cmaes_holds_fixed_coordinates_and_searches_the_others_as_without_them(tmp_path):
    x0 = np.array([0.5, 3.0, -0.2])
    fixed = CMAES(x0, 0.3, np.random.default_rng(1), popsize=6, bounds=np.array([[-2, 2], [-5, 5], [-2, 2]]), fixed=[1],
                  cma_options={"CMA_stds": [1.0, 1.0, 1.0]})
    free = CMAES(x0[[0, 2]], 0.3, np.random.default_rng(1), popsize=6, bounds=np.array([[-2, 2], [-2, 2]]))
    for _ in range(15):
        X, Y = fixed.ask(), free.ask()
        assert np.all(X[:, 1] == 3.0) and np.allclose(X[:, [0, 2]], Y)
        r = -np.sum((Y - 0.1) ** 2, axis=1)
        fixed.tell(X, r)
        free.tell(Y, r)
    assert np.allclose(fixed.mean[[0, 2]], free.mean) and fixed.mean[1] == 3.0
    save_state(fixed.state_dict(), tmp_path / "opt")
    back = CMAES.from_state(load_state(tmp_path / "opt"))
    assert np.array_equal(back.ask(), fixed.ask())
    for bad in ([3], [0, 1, 2]):
        with pytest.raises(ValueError):
            CMAES(x0, 0.3, np.random.default_rng(0), fixed=bad)


def test_scouts_keep_their_start_points_fixed_value_and_a_resumed_run_asks_the_same(tmp_path):
    starts = np.array([[-3.0, -3.0, 0.0], [2.0, 2.0, 1.0]])
    bounds = np.array([[-10.0, 10.0], [-10.0, 10.0], [-0.5, 1.5]])

    def opt():
        return StagnationRestartCMAES(starts, 0.5, np.random.default_rng(0), popsize=6, bounds=bounds, stagnation_generations=4,
                                      restart_from_best=True, scouts=2, scout_generations=3, fixed=[2])

    def f(X):  # the fixed coordinate shifts the optimum: family 1's is the better one
        return -np.sum((X[:, :2] - 1.0 - X[:, 2:]) ** 2, axis=1) - 0.5 * (X[:, 2] == 0)

    a = opt()
    for g in range(30):
        X = a.ask()
        assert len(set(X[:, 2])) == 1
        if g < 3:
            assert np.all(X[:, 2] == 0.0)  # scout 0
        elif g < 6:
            assert np.all(X[:, 2] == 1.0)  # scout 1
        a.tell(X, f(X))
        if g == 12:
            save_state(a.state_dict(), tmp_path / "opt")
            b = StagnationRestartCMAES.from_state(load_state(tmp_path / "opt"))
    assert a.best[0][2] == 1.0 and a.best[1] > -0.01
    assert any(e["start"] == -1 for e in a.attempt_history)  # a restart from the best, in the best's family
    c = opt()
    for _ in range(13):
        X = c.ask()
        c.tell(X, f(X))
    for _ in range(17):
        Xb, Xc = b.ask(), c.ask()
        assert np.array_equal(Xb, Xc)
        b.tell(Xb, f(Xb))
        c.tell(Xc, f(Xc))


def test_refine_races_each_family_and_saves_the_best_throws_own_dmp(base, tmp_path):
    from besdrake.tasks.throwing.reward import ThrowReward

    other = base.copy()  # another imitated throw within the limits: its own goal velocity
    other.goal_velocity = other.goal_velocity + np.array([0.0, 0.6, 0.0, 0.0, 0.5, 0.0])

    class Swing:  # lands by the swing's final velocity alone: only the other throw's goal velocity gets near
        def evaluate(self, plans):
            return [outcome([2.0 + 0.5 * p.qd[-1, 1], 0.5 * p.qd[-1, 4]]) for p in plans]

    end = RefinementProblem(COMPI, other, retime=False).plan(np.zeros(49))
    reward = ThrowReward(target=(2.0 + 0.5 * end.qd[-1, 1], 0.5 * end.qd[-1, 4]))
    p0, p1 = [RefinementProblem(COMPI, d, reward, retime=False) for d in (base, other)]
    run = family_run([p0, p1], [0, 1], group=0, n=2)
    kw = dict(seed=0, popsize=8, stagnation_generations=4, starts=run.starts, scouts=2, scout_generations=2, stop_on_success=False)
    result = refine(run.problem, Swing(), n_episodes=48, out_dir=tmp_path, **kw)
    scout0, scout1 = result.attempts[:2]
    assert scout1["best_reward"] > -0.05 > scout0["best_reward"]  # the other throw's own movement, not a hybrid
    assert np.allclose(result.best_dmp.goal_velocity, other.goal_velocity)
    again = refine(RefinementProblem.from_description(run.problem.describe()), Swing(), n_episodes=64, out_dir=tmp_path, **kw)
    whole = refine(RefinementProblem.from_description(run.problem.describe()), Swing(), n_episodes=64, **kw)
    assert again.resumed and again.n_episodes == 64
    assert np.array_equal(whole.rewards, again.rewards)  # a killed run resumes to the same end
