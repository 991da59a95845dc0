"""Robust refinement (issue 27): candidates near the goal re-simulated under the setup's scatter, their reward the RMS
distance over it; the stop margin; a plan's lab repetitions against the lab's noise floor."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from besdrake.robot import load_robot
from besdrake.search.refinement import RefinementError, RefinementProblem, read_details, refine
from besdrake.search.refinement.robust import RobustCheck
from besdrake.search.reward import RewardBreakdown
from besdrake.task import get_task
from besdrake.tasks.throwing.outcome import FLAG_NAMES, Outcome
from besdrake.tasks.throwing.template_base import fitted_default_throw

logging.getLogger("drake").setLevel(logging.ERROR)
COMPI = load_robot("compi")


@pytest.fixture(scope="module")
def base():
    return fitted_default_throw()


class ScatterStandIn:
    """No physics: x = goal of joint 2 + 1 m, y = goal of joint 1; a ball placed off-centre along x moves the touchdown
    by ``gain`` times the offset, and by 0.5 m more where the goal of joint 3 is above ``cliff`` (a plan on a cliff)."""

    def __init__(self, gain: float = 10.0, cliff: float = np.inf) -> None:
        self.gain, self.cliff = gain, cliff
        self.calls = 0
        self.perturbed = 0

    def evaluate(self, plans, effects=None):
        effs = effects if isinstance(effects, list) else [effects] * len(plans)
        out = []
        for p, e in zip(plans, effs):
            self.calls += 1
            dx = 0.0 if not e else e["ball_placement"]["x"]
            self.perturbed += bool(e)
            x = p.q[-1, 1] + 1.0 + self.gain * dx + (0.5 * abs(np.sign(dx)) if p.q[-1, 2] > self.cliff else 0.0)
            o = Outcome(flags={k: False for k in FLAG_NAMES})
            o.touchdown = np.array([x, p.q[-1, 0]])
            out.append(o)
        return out


def placement_check(sd: float = 0.002, radius: float = 0.3, probe_tolerance: float | None = 0.01, frontier: float | None = 0.01) -> RobustCheck:
    from besdrake.sim.scenario import load_scenario

    return RobustCheck.from_task(get_task("throwing"), load_scenario("nominal"), sd, radius=radius, probe_tolerance=probe_tolerance,
                                 frontier=frontier)


def test_robust_reward_is_the_rms_distance_over_the_quadrature():
    check = placement_check()
    assert check.n_rollouts == 8 and check.weights.sum() == pytest.approx(1.0)
    nominal = RewardBreakdown(-0.05, 0.05, 0.0, (1.95, 0.0))
    d = np.array([0.05, 0.05, 0.05, 0.02, 0.08, 0.3, 0.05, 0.05])
    perturbed = [RewardBreakdown(-v, v, 0.0, (2.0 - v, 0.0)) for v in d]
    r = check.combine(nominal, perturbed)
    rms = np.sqrt(check.weights @ np.r_[0.05, d] ** 2)
    assert r.robust_distance == pytest.approx(rms) and r.reward == pytest.approx(-rms)
    assert r.distance == 0.05 and r.touchdown == (1.95, 0.0) and r.robust_rollouts == 8  # the nominal outcome is kept
    skipped = check.combine(nominal, [perturbed[0]] + [None] * 7)  # setups not simulated count as the nominal
    assert skipped.robust_distance == pytest.approx(0.05) and skipped.robust_rollouts == 1
    a, b = (check.effects[k]["ball_placement"] for k in check.probes())
    assert a["x"] == -b["x"] != 0 and a["y"] == -b["y"] != 0  # the probes: two opposite corners of the rule
    assert placement_check(probe_tolerance=None).probes() == list(range(8))
    failed = check.combine(nominal, [RewardBreakdown(np.nan, np.nan, np.nan, None)] * 8)
    assert failed.robust_distance == pytest.approx(np.sqrt(check.weights[0] * 0.05**2 + 1 - check.weights[0]))  # a miss: 1 m
    assert check.needs(nominal) and not check.needs(RewardBreakdown(-0.5, 0.4, 0.0, (1.6, 0.0)))
    assert not check.needs(RewardBreakdown(-1.05, 0.05, 1.0, (1.95, 0.0)))  # beyond a limit: not checked
    assert RobustCheck.from_dict(check.to_dict()).to_dict() == check.to_dict()
    assert RobustCheck.from_task(get_task("throwing"), None, 0.0) is None  # no scatter: no check
    with pytest.raises(RefinementError):
        RobustCheck([{"ball_placement": {"x": 0.001}}], [0.5, 0.6])
    with pytest.raises(RefinementError):
        RobustCheck([{"ball_placement": {"x": 0.001}}], [0.5, 0.5], radius=0.0)


def test_only_candidates_near_the_goal_are_rechecked_and_a_cliff_ranks_lower(base):
    check = placement_check()
    problem = RefinementProblem(COMPI, base, robust=check)
    n = problem.parameterization.template.n_dims
    theta0, scale = problem.scaling.theta0, problem.scaling.scale
    # candidate 0 lands far off (no check), 1 and 2 at about (1.95, 0) m, 2 on a cliff (goal of joint 3 raised)
    X = np.zeros((3, problem.n_params))
    X[1:, n] = (0.0 - theta0[n]) / scale[n]
    X[1:, n + 1] = (0.95 - theta0[n + 1]) / scale[n + 1]
    X[2, n + 2] = 0.5
    ex = ScatterStandIn(gain=0.0, cliff=base.goal[2] + 0.1)
    r = problem.evaluate(X, ex)
    assert ex.perturbed == 2 + 8 and ex.calls == 3 + 10  # candidate 1 stays put under both probes, 2 is checked fully
    assert r[1].robust_rollouts == 2 and r[2].robust_rollouts == 8
    assert not np.isfinite(r[0].robust_distance) and r[0].reward == pytest.approx(-r[0].distance)
    assert r[1].distance == pytest.approx(r[2].distance, abs=1e-6) and r[1].distance < 0.1
    assert r[2].robust_distance > r[1].robust_distance + 0.2 and r[2].reward < r[1].reward
    assert RefinementProblem.from_description(problem.describe()).robust.to_dict() == check.to_dict()


def test_only_candidates_that_could_become_the_runs_best_are_checked(base):
    problem = RefinementProblem(COMPI, base, robust=placement_check())
    n = problem.parameterization.template.n_dims
    theta0, scale = problem.scaling.theta0, problem.scaling.scale
    X = np.zeros((2, problem.n_params))  # both land about 5 cm short of the target, one on a cliff
    X[:, n] = (0.0 - theta0[n]) / scale[n]
    X[:, n + 1] = (0.95 - theta0[n + 1]) / scale[n + 1]
    X[1, n + 2] = 0.5
    ex = ScatterStandIn(gain=0.0, cliff=base.goal[2] + 0.1)
    evaluate = problem.batch_evaluator(ex)
    first = evaluate(X)  # nothing recorded before: both checked, the cliff ranks lower
    assert ex.perturbed == 2 + 8 and first[1] < first[0]
    again = problem.evaluate(X, ex_again := ScatterStandIn(gain=0.0, cliff=base.goal[2] + 0.1))
    assert ex_again.perturbed == 10 and again[1].reward == pytest.approx(first[1])  # the batch's own records left out
    problem.records["better"] = RewardBreakdown(-0.02, 0.02, 0.0, (1.98, 0.0), robust_distance=0.02)
    ex = ScatterStandIn(gain=0.0, cliff=base.goal[2] + 0.1)
    behind = problem.evaluate(X, ex)  # 5 cm against a best of 2 cm: neither can become the best, neither is checked
    assert ex.perturbed == 0 and all(not np.isfinite(r.robust_distance) and r.reward == pytest.approx(-r.distance) for r in behind)
    problem.records["better"] = RewardBreakdown(-0.045, 0.045, 0.0, (1.955, 0.0), robust_distance=0.045)
    ex = ScatterStandIn(gain=0.0, cliff=base.goal[2] + 0.1)
    near = problem.evaluate(X, ex)  # within the 1 cm margin of the best: checked
    assert ex.perturbed == 10 and near[1].reward == pytest.approx(first[1])
    everyone = RefinementProblem(COMPI, base, robust=placement_check(frontier=None))
    everyone.records["better"] = RewardBreakdown(-0.02, 0.02, 0.0, (1.98, 0.0), robust_distance=0.02)
    ex = ScatterStandIn(gain=0.0, cliff=base.goal[2] + 0.1)
    everyone.evaluate(X, ex)
    assert ex.perturbed == 10  # without a frontier every candidate within the radius is checked
    assert "frontier" not in everyone.robust.to_dict() and RobustCheck.from_dict(problem.robust.to_dict()).frontier == 0.01


def test_a_frontier_run_checks_its_best_and_fewer_others(base):
    runs = {f: refine(RefinementProblem(COMPI, base, robust=placement_check(frontier=f)), ScatterStandIn(), n_episodes=200, seed=1,
                      popsize=10, stop_on_success=False) for f in (None, 0.01)}
    lazy, full = runs[0.01], runs[None]
    assert 0 < lazy.n_robust_rollouts < full.n_robust_rollouts
    best = int(np.argmax(lazy.rewards))
    assert np.isfinite(lazy.robust_distances[best]) and lazy.best_robust_distance == lazy.robust_distances[best]


def test_a_robust_run_records_its_checks_resumes_and_stops_inside_the_margin(base, tmp_path):
    problem = RefinementProblem(COMPI, base, robust=placement_check())
    first = refine(problem, ScatterStandIn(), n_episodes=30, seed=1, popsize=10, out_dir=tmp_path, stop_on_success=False)
    details = read_details(tmp_path / "details.csv")
    assert len(details) == 30
    again = refine(RefinementProblem(COMPI, base, robust=placement_check()), ScatterStandIn(), n_episodes=30, seed=1, popsize=10,
                   out_dir=tmp_path, stop_on_success=False)
    assert again.resumed and np.array_equal(np.isfinite(again.robust_distances), np.isfinite(first.robust_distances))
    assert first.n_robust_rollouts == 8 * int(np.isfinite(first.robust_distances).sum())  # gain 10: no probe stays put
    with pytest.raises(RefinementError, match="stop_distance"):
        refine(RefinementProblem(COMPI, base), ScatterStandIn(), n_episodes=10, stop_distance=0.2)
    loose = refine(RefinementProblem(COMPI, base, robust=placement_check()), ScatterStandIn(), n_episodes=3000, seed=1)
    tight = refine(RefinementProblem(COMPI, base, robust=placement_check()), ScatterStandIn(), n_episodes=3000, seed=1, stop_distance=0.03)
    assert loose.success and tight.success and tight.n_episodes >= loose.n_episodes
    assert tight.best_robust_distance < 0.03 and tight.summary()["robust_rollouts"] == tight.n_robust_rollouts


def test_lab_repetitions_against_the_noise_floor(tmp_path):
    from besdrake.tasks.throwing.repeatability import DEFAULT_LAB, lab_repeatability, pooled_sd
    from besdrake.tasks.throwing.throws import default_throw

    plan = default_throw()
    rep = lab_repeatability(plan, DEFAULT_LAB, repeats=3, seed=0)
    s = rep.summary()
    assert s["repeats"] == 3 and s["n_missing"] == 0 and rep.floor > 0 and np.isfinite(rep.ratio)
    assert not np.allclose(rep.touchdowns, rep.floor_touchdowns)  # the placement moves the touchdown
    still = tmp_path / "still_lab.yaml"
    still.write_text(DEFAULT_LAB.read_text().replace("ball_placement_sd: 0.002", "ball_placement_sd: 0.0"))
    same = lab_repeatability(plan, still, repeats=3, seed=0)
    assert same.ratio == pytest.approx(1.0) and np.allclose(same.touchdowns, rep.floor_touchdowns)
    assert pooled_sd(np.array([[0.0, 0.0], [np.nan, 1.0], [2.0, 0.0]])) == pytest.approx(1.0)  # rows without a touchdown left out
    with pytest.raises(ValueError):
        lab_repeatability(plan, DEFAULT_LAB, repeats=1)


def test_a_run_that_stopped_on_success_stays_stopped_when_resumed(base, tmp_path):
    first = refine(RefinementProblem(COMPI, base), ScatterStandIn(), n_episodes=3000, seed=1, out_dir=tmp_path)
    assert first.success and first.stop_reason == "callback"
    ex = ScatterStandIn()
    again = refine(RefinementProblem(COMPI, base), ex, n_episodes=3000, seed=1, out_dir=tmp_path)
    assert ex.calls == 0 and again.n_episodes == first.n_episodes and again.episodes_to_success == first.episodes_to_success


def test_learn_keeps_a_start_throw_within_the_stop_distance_and_refines_one_beyond_it(base, tmp_path):
    from besdrake.pipeline.config import load_config
    from besdrake.pipeline.learn import Context
    from besdrake.sim import make_executor
    from besdrake.tasks.throwing.learn.refinement import refine_from as _refine_from

    with make_executor("serial") as ex:
        td = RefinementProblem(COMPI, base).evaluate(np.zeros((1, 49)), ex)[0].touchdown
    target = [f"refinement.target=[{td[0] + 0.02}, {td[1]}]", "workers=1", "refinement.plans=1", "refinement.robust_sd=0"]
    said = []
    ctx = Context(run=None, config=load_config(overrides=target), progress=said.append)
    kept = _refine_from(ctx, [base], "nominal", tmp_path / "kept", 20, "test")
    assert kept["runs"][0]["n_episodes"] == 0 and kept["best_distance_within_limits_m"] == pytest.approx(0.02, abs=1e-3)
    assert (tmp_path / "kept" / "refined0.dmp.json").is_file() and not (tmp_path / "kept" / "run0").exists()
    assert "kept, no CMA-ES run" in said[-1]
    ctx = Context(run=None, config=load_config(overrides=target + ["refinement.stop_distance=0.01"]), progress=said.append)
    refined = _refine_from(ctx, [base], "nominal", tmp_path / "refined", 20, "test")
    assert refined["runs"][0]["n_episodes"] >= 20 and (tmp_path / "refined" / "run0" / "episodes.csv").is_file()
