"""Refinement in simulation: reward and penalties, normalised space, CMA-ES runs, failures, resume, CLI."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from besdrake.imitation import DMPParameterization
from besdrake.plan import MotionPlan
from besdrake.search.refinement import (
    MAX_EXECUTION_TIME,
    MIN_EXECUTION_TIME,
    SUCCESS_DISTANCE,
    ParameterScaling,
    RefinementError,
    RefinementProblem,
    best_start,
    read_details,
    refine,
)
from besdrake.tasks.throwing.template_base import fitted_default_throw
from besdrake.tasks.throwing.outcome import FLAG_NAMES, Outcome
from besdrake.tasks.throwing.reward import ThrowReward

logging.getLogger("drake").setLevel(logging.ERROR)


from besdrake.robot import load_robot

COMPI = load_robot("compi")


def outcome(touchdown=None, ball_end=None, **flags) -> Outcome:
    f = {k: False for k in FLAG_NAMES} | flags
    o = Outcome(flags=f)
    if touchdown is not None:
        o.touchdown = np.asarray(touchdown, dtype=float)
    if ball_end is not None:
        o.ball_path = np.asarray([[0.0, 0.0, 1.0], ball_end], dtype=float)
    return o


@pytest.fixture(scope="module")
def base():
    return fitted_default_throw()


@pytest.fixture(scope="module")
def plan_ok(base):
    return DMPParameterization(base).motion_plan(DMPParameterization(base).to_vector(), dt=0.01)


class StandIn:
    """Cheap stand-in for the simulation: x = goal of joint 2 + 1 m, y = goal of joint 1 (no physics)."""

    def __init__(self, fail_every: int = 0, raise_every: int = 0) -> None:
        self.calls = 0
        self.fail_every, self.raise_every = fail_every, raise_every

    def evaluate(self, plans):
        out = []
        for p in plans:
            self.calls += 1
            if self.raise_every and self.calls % self.raise_every == 0:
                raise RuntimeError("worker died")
            if self.fail_every and self.calls % self.fail_every == 0:
                out.append(outcome(sim_failed=True))
            else:
                out.append(outcome([p.q[-1, 1] + 1.0, p.q[-1, 0]]))
        return out


# ------------------------------------------------------------------------------------------ reward
def test_reward_is_minus_distance_within_limits(plan_ok):
    assert plan_ok.check_limits(COMPI.limits).ok
    r = ThrowReward(target=(2.0, 0.0))(plan_ok, outcome([1.7, 0.4]), COMPI.limits)
    assert r.reward == pytest.approx(-0.5) and r.distance == pytest.approx(0.5) and r.penalty == 0.0
    assert not r.success
    near = ThrowReward()(plan_ok, outcome([1.95, 0.05]), COMPI.limits)
    assert near.success and near.reward > r.reward


def test_reward_decreases_with_distance(plan_ok):
    rew = ThrowReward(target=(2.0, 0.5))
    values = [rew(plan_ok, outcome([2.0 - d, 0.5]), COMPI.limits).reward for d in (0.0, 0.1, 0.5, 1.5)]
    assert all(a > b for a, b in zip(values, values[1:]))


def test_limit_penalties_make_a_hit_worse_than_a_near_miss(plan_ok):
    fast = MotionPlan(plan_ok.t * 0.5, plan_ok.q, None if plan_ok.qd is None else plan_ok.qd * 2.0)
    rep = fast.check_limits(COMPI.limits)
    assert not rep.ok
    rew = ThrowReward()
    hit_fast = rew(fast, outcome([2.0, 0.0]), COMPI.limits)
    assert hit_fast.penalty >= rew.violation_offset and not hit_fast.success
    assert hit_fast.reward < rew(plan_ok, outcome([2.0 - SUCCESS_DISTANCE, 0.0]), COMPI.limits).reward
    # more violation, more penalty
    faster = MotionPlan(plan_ok.t * 0.4, plan_ok.q, None if plan_ok.qd is None else plan_ok.qd * 2.5)
    assert rew.penalty(faster, COMPI.limits) > rew.penalty(fast, COMPI.limits)


def test_never_released_is_shaped_and_penalised(plan_ok):
    rew = ThrowReward()
    kept = rew(plan_ok, outcome(None, ball_end=[0.5, 0.0, 1.0], never_released=True), COMPI.limits)
    dropped = rew(plan_ok, outcome([0.5, 0.0], dropped_early=True), COMPI.limits)
    assert np.isfinite(kept.reward) and kept.reward == pytest.approx(dropped.reward + rew.dropped_penalty - rew.never_released_penalty)
    closer = rew(plan_ok, outcome(None, ball_end=[1.0, 0.0, 1.0], never_released=True), COMPI.limits)
    assert closer.reward > kept.reward


def test_failed_simulation_gives_nan(plan_ok):
    r = ThrowReward()(plan_ok, outcome(sim_failed=True), COMPI.limits)
    assert np.isnan(r.reward) and r.failed


@pytest.mark.parametrize("target", [(np.nan, 0.0), (1.0,), "far"])
def test_bad_target_is_rejected(target):
    with pytest.raises(RefinementError, match="target"):
        ThrowReward(target=target)


# ------------------------------------------------------------------------------------------ scaling
def test_scaling_round_trip_and_bounds(base):
    sc = ParameterScaling.for_dmp(base, COMPI.position_limits)
    assert sc.theta0.size == 49
    rng = np.random.default_rng(0)
    x = rng.normal(size=49)
    theta = sc.to_theta(x)
    assert np.all(theta >= sc.bounds[:, 0]) and np.all(theta <= sc.bounds[:, 1])
    assert np.allclose(sc.to_x(theta), x)
    assert np.allclose(sc.to_theta(np.zeros(49)), DMPParameterization(base).to_vector())
    assert sc.bounds[-1].tolist() == [MIN_EXECUTION_TIME, MAX_EXECUTION_TIME]
    w = sc.scale[12:48].reshape(6, 6)
    assert np.all(np.diff(w, axis=1) > 0)  # late weights act through a smaller phase: larger steps
    xb = sc.x_bounds
    assert np.all(xb[:, 0] < 0) and np.all(xb[:, 1] > 0)


def test_scaling_rejects_bad_input(base):
    with pytest.raises(RefinementError):
        ParameterScaling(np.zeros(3), np.array([1.0, 0.0, 1.0]), np.tile([-1.0, 1.0], (3, 1)))
    with pytest.raises(RefinementError):
        ParameterScaling.for_dmp(base, COMPI.position_limits, acceleration_unit=float("nan"))


# ------------------------------------------------------------------------------------------ search
def test_cma_refines_stand_in_problem_to_success(base):
    problem = RefinementProblem(COMPI, base)
    start = problem.evaluate(np.zeros((1, 49)), StandIn())[0]
    assert start.distance > 0.9
    result = refine(problem, StandIn(), n_episodes=1500, seed=1)
    assert result.success, result.summary()
    assert result.episodes_to_success <= result.n_episodes <= 1500
    assert result.best_distance < SUCCESS_DISTANCE
    assert np.nanmin(result.best_so_far()) < SUCCESS_DISTANCE


def test_failed_episodes_are_recorded_and_search_goes_on(base, tmp_path):
    problem = RefinementProblem(COMPI, base)
    ex = StandIn(fail_every=3, raise_every=37)
    result = refine(problem, ex, n_episodes=80, seed=0, popsize=8, out_dir=tmp_path, stop_on_success=False)
    assert result.n_episodes == 80
    assert result.n_failed >= 80 // 3
    rows = (tmp_path / "episodes.csv").read_text().splitlines()
    assert len(rows) == 81  # header + every episode, failed ones included
    assert np.isfinite(result.best_reward)


def test_nan_candidate_is_a_failed_episode(base):
    problem = RefinementProblem(COMPI, base)
    X = np.zeros((3, 49))
    X[1, 5] = np.nan
    res = problem.evaluate(X, StandIn())
    assert [r.failed for r in res] == [False, True, False]
    assert "NaN" in res[1].message


def test_resume_continues_without_repeating(base, tmp_path):
    problem = RefinementProblem(COMPI, base)
    first = refine(problem, StandIn(), n_episodes=24, seed=3, popsize=8, out_dir=tmp_path, stop_on_success=False)
    assert first.n_episodes == 24 and not first.resumed
    ex = StandIn()
    again = refine(RefinementProblem(COMPI, base), ex, n_episodes=48, seed=3, popsize=8, out_dir=tmp_path, stop_on_success=False)
    assert again.resumed and again.n_episodes == 48 and ex.calls == 24
    assert np.isfinite(again.distances).all()  # per-episode records of the first part were read back
    assert len(read_details(tmp_path / "details.csv")) == 48
    with pytest.raises(RefinementError, match="another refinement"):
        refine(RefinementProblem(COMPI, base, ThrowReward(target=(1.5, 0.0))), StandIn(), n_episodes=60, seed=3, popsize=8, out_dir=tmp_path)


def test_a_few_generations_on_the_real_simulation_improve_the_distance(base):
    from besdrake.sim import make_executor

    slow = base.copy()
    slow.execution_time = 2.3  # the fitted throw, slowed down: lands ~0.8 m short of the target
    problem = RefinementProblem(COMPI, slow)
    with make_executor("serial") as ex:
        index, start = best_start([problem], ex)
        assert index == 0 and start.distance > 0.5
        result = refine(problem, ex, n_episodes=24, seed=0, popsize=8, sigma0=1.0)
    assert result.n_failed == 0
    assert np.nanmin(result.distances) < start.distance - 0.05


def test_refine_cli_writes_summary_figure_and_resumes(base, tmp_path):
    from besdrake.cli import main
    from besdrake.imitation import save_dmp

    slow = base.copy()
    slow.execution_time = 2.3
    dmp_file = save_dmp(slow, tmp_path / "throw.dmp.json")
    out = tmp_path / "run"
    argv = [ "refine", str(dmp_file), "--out", str(out), "--episodes", "8", "--popsize", "4", "--backend", "serial", "--quiet", "--json"]
    assert main(argv) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["runs"][0]["n_episodes"] == 8 and (out / "learning_curve.png").stat().st_size > 0
    assert (out / "run0" / "refined.dmp.json").is_file()
    argv[argv.index("8")] = "12"
    assert main(argv) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["runs"][0]["resumed"] and summary["runs"][0]["n_episodes"] == 12
    assert main(["refine", str(tmp_path / "missing.dmp.json"), "--out", str(out), "--backend", "serial"]) == 2
    assert main(argv[:argv.index("--out") + 1] + [str(tmp_path / "stall")] + argv[argv.index("--out") + 2:] + ["--stall-episodes", "0"]) == 2
    assert main(argv[:argv.index("--out") + 1] + [str(tmp_path / "switch")] + argv[argv.index("--out") + 2:] + ["--switch-distance", "0"]) == 2


def test_retiming_stretches_a_plan_beyond_the_speed_limits_and_leaves_others_alone(base):
    problem = RefinementProblem(COMPI, base, retime=True)
    plain = RefinementProblem(COMPI, base, retime=False)
    x_ok = np.zeros(problem.n_params)
    vel, acc = plain.plan(x_ok).peak_limit_ratios(COMPI.limits)
    assert max(vel.max(), acc.max()) <= 1.0  # the default throw keeps its limits: nothing to mend
    assert np.array_equal(problem.theta(x_ok), plain.theta(x_ok))
    # the same throw at the shortest execution time breaks a velocity or acceleration limit ...
    x_fast = x_ok.copy()
    x_fast[-1] = problem.scaling.x_bounds[-1, 0]
    vel, acc = plain.plan(x_fast).peak_limit_ratios(COMPI.limits)
    k = max(vel.max(), np.sqrt(acc.max()))
    assert k > 1.2
    # ... and retimed it is stretched by about that factor and keeps them (a stretch divides velocities by k)
    theta = problem.theta(x_fast)
    assert np.array_equal(theta[:-1], plain.theta(x_fast)[:-1])
    assert theta[-1] == pytest.approx(plain.theta(x_fast)[-1] * k, rel=0.05)
    vel, acc = problem.plan(x_fast).peak_limit_ratios(COMPI.limits)
    assert vel.max() <= 1.0 + 1e-6 and acc.max() <= 1.0 + 1e-6
    assert ThrowReward().penalty(problem.plan(x_fast), COMPI.limits) == 0.0 < ThrowReward().penalty(plain.plan(x_fast), COMPI.limits)
    # never beyond the execution-time bound; the setting travels with the problem's record
    tight = RefinementProblem(COMPI, base, scaling=ParameterScaling.for_dmp(base, COMPI.position_limits, max_execution_time=MIN_EXECUTION_TIME + 0.01), retime=True)
    assert tight.theta(np.full(tight.n_params, 0.0))[-1] <= MIN_EXECUTION_TIME + 0.01
    assert RefinementProblem.from_description(json.loads(json.dumps(problem.describe()))).retime
    assert "retime" not in plain.describe() and not RefinementProblem.from_description(plain.describe()).retime


def test_a_candidates_plan_is_the_rollout_of_its_retimed_parameters(base):
    """plan(x) reuses the retiming's last rollout: the same arrays as rolling theta(x) out afresh."""
    problem = RefinementProblem(COMPI, base, retime=True)
    x_fast = np.zeros(problem.n_params)
    x_fast[-1] = problem.scaling.x_bounds[-1, 0]  # stretched by the retiming
    rng = np.random.default_rng(3)
    for x in (np.zeros(problem.n_params), x_fast, rng.normal(size=problem.n_params)):
        plan = problem.plan(x)
        fresh = problem.parameterization.motion_plan(problem.theta(x), dt=problem.dt)
        assert np.array_equal(plan.t, fresh.t) and np.array_equal(plan.q, fresh.q) and np.array_equal(plan.qd, fresh.qd)
        assert plan.meta == fresh.meta
        assert np.array_equal(plan.check_limits(COMPI.limits).acceleration, fresh.check_limits(COMPI.limits).acceleration)


def test_episode_bench_splits_the_episodes_time(base):
    from besdrake.tasks.throwing.episode_bench import PARTS, run_episode_bench

    slow = base.copy()
    slow.execution_time = 2.3
    problem = RefinementProblem(COMPI, slow)
    res = run_episode_bench(problem, n_episodes=10, seed=0)  # one generation
    assert res.n_episodes == 10 and set(res.ms_per_episode) == set(PARTS)
    parts = sum(v for k, v in res.ms_per_episode.items() if k != "release_checks")
    assert parts == pytest.approx(res.episode_cpu_ms, abs=0.01)  # the parts are rounded to 1 us
    assert res.ms_per_episode["simulation"] > res.ms_per_episode["release_checks"] > 0 and res.ms_per_episode["dmp_rollout"] > 0
    assert res.rollout_cpu_ms > 0 and res.ratio_to_rollout == pytest.approx(res.episode_cpu_ms / res.rollout_cpu_ms)
    assert res.sim_s_per_episode > 0 and res.default_throw_sim_s > 0 and "episode / rollout" in res.table()
    # the instrumentation is gone afterwards
    assert "plan" not in vars(problem) and "motion_plan" not in vars(problem.parameterization)
    assert isinstance(problem.reward, ThrowReward)


def test_a_far_stall_rule_holds_only_beyond_its_distance_and_any_rule_ends_a_run(base):
    """StallRule(beyond=...): stalled only while the best is still farther than that; AnyStall: by any of its rules (a
    run ends by the quicker far rule while the usual one would still wait)."""
    from besdrake.search.refinement import AnyStall, StallRule

    far = StallRule(episodes=4, tol=0.01, after=0, beyond=0.25)
    assert far.stalled([0.4] * 5) and not far.stalled([0.2] * 5) and not far.stalled([0.5, 0.45, 0.4, 0.35, 0.3])
    with pytest.raises(RefinementError):
        StallRule(beyond=-0.1)
    usual = StallRule(episodes=16, tol=0.01, after=40)
    either = AnyStall((usual, far))
    assert either.stalled([0.4] * 5) and not usual.stalled([0.4] * 5) and not either.stalled([0.2] * 20)
    run = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=80, seed=3, popsize=8, stop_on_success=False,
                 stall=AnyStall((usual, StallRule(episodes=16, tol=10.0, after=24, beyond=0.0))))
    assert run.n_episodes == 24 and run.stop_reason == "stalled"


def test_a_stall_rule_ends_a_run_that_gained_too_little_and_a_resumed_run_ends_alike(base, tmp_path):
    from besdrake.search.refinement import StallRule

    rule = StallRule(episodes=16, tol=0.01, after=0)
    assert not rule.stalled([1.0, 0.9] * 8) and rule.stalled([1.0] * 17) and not rule.stalled([1.0] * 16 + [0.9])
    assert StallRule(16, 0.05, after=0).stalled([1.0] * 8 + [0.98] * 9) and not StallRule(16, 0.05, after=40).stalled([1.0] * 17)
    assert not StallRule(2, 0.01, after=0).stalled([np.nan, np.nan, 1.0])  # a first finite best is a gain
    for bad in ({"episodes": 0}, {"tol": -0.01}, {"after": -1}, {"tol": float("nan")}):
        with pytest.raises(RefinementError):
            StallRule(**bad)

    never = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=48, seed=3, popsize=8, stop_on_success=False,
                   stall=StallRule(episodes=16, tol=0.0, after=24))
    assert never.n_episodes == 48 and never.stop_reason == "budget"  # a gain below 0 m: never
    huge = StallRule(episodes=16, tol=10.0, after=24)  # any run "gains too little" once it has 24 episodes
    whole = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=80, seed=3, popsize=8, stop_on_success=False, stall=huge)
    assert whole.n_episodes == 24 and whole.stop_reason == "stalled"
    refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=16, seed=3, popsize=8, out_dir=tmp_path, stop_on_success=False, stall=huge)
    ex = StandIn()
    resumed = refine(RefinementProblem(COMPI, base), ex, n_episodes=80, seed=3, popsize=8, out_dir=tmp_path, stop_on_success=False, stall=huge)
    assert resumed.resumed and resumed.n_episodes == 24 and ex.calls == 8 and resumed.stop_reason == "stalled"
    assert np.array_equal(resumed.rewards, whole.rewards)
    ex = StandIn()
    again = refine(RefinementProblem(COMPI, base), ex, n_episodes=80, seed=3, popsize=8, out_dir=tmp_path, stop_on_success=False, stall=huge)
    assert again.n_episodes == 24 and ex.calls == 0 and again.stop_reason == "stalled"  # a stalled run stays stopped
