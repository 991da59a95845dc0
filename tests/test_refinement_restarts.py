"""Refinement with stagnation restarts: StagnationRestartCMAES (plateau detection, start points, resume),
rank_starts/restart_points and refine(stagnation_generations=...)."""

from __future__ import annotations

import numpy as np
import pytest

from besdrake.search.base import load_state, save_state
from besdrake.search.cmaes import StagnationRestartCMAES
from besdrake.search.refinement import (DEFAULT_SCOUT_GENERATIONS, DEFAULT_SCOUTS, RefinementError, RefinementProblem, rank_starts, refine,
                                        restart_points, run_start_order, scout_start_points)
from besdrake.tasks.throwing.template_base import fitted_default_throw
from besdrake.tasks.throwing.reward import ThrowReward
from tests.test_refinement import StandIn


from besdrake.robot import load_robot

COMPI = load_robot("compi")


def two_basins(X: np.ndarray) -> np.ndarray:
    """A deceptive landscape: a broad local optimum (-0.5) at -3 and the global one (0) at +3."""
    X = np.atleast_2d(X)
    return -np.minimum(np.sum((X - 3.0) ** 2, axis=1), 0.5 + 0.1 * np.sum((X + 3.0) ** 2, axis=1))


def run(opt, generations: int) -> None:
    for _ in range(generations):
        X = opt.ask()
        opt.tell(X, two_basins(X))


def restored(a, tmp_path):
    """``a`` saved to disk and restored as a new optimizer."""
    save_state(a.state_dict(), tmp_path / "opt")
    return StagnationRestartCMAES.from_state(load_state(tmp_path / "opt"))


def assert_same_asks(a, b, generations: int) -> None:
    """``a`` and ``b`` side by side on the two-basin function ask identical candidates and record the same attempts."""
    for _ in range(generations):
        Xa, Xb = a.ask(), b.ask()
        assert np.array_equal(Xa, Xb)
        a.tell(Xa, two_basins(Xa))
        b.tell(Xb, two_basins(Xb))
    assert a.attempt_history == b.attempt_history


def test_a_stalled_attempt_restarts_from_the_next_start_point():
    n = 5
    starts = np.array([[-3.0] * n, [2.0] * n])
    opt = StagnationRestartCMAES(starts, 0.5, np.random.default_rng(0), popsize=8, bounds=np.tile([-10.0, 10.0], (n, 1)),
                                 stagnation_generations=5, tol=0.01)
    run(opt, 80)
    assert len(opt.attempt_history) >= 1
    first = opt.attempt_history[0]
    assert first["start"] == 0 and first["end"] in ("stagnation", "cma") and first["best_reward"] <= -0.5 + 1e-9
    assert opt.attempt_history[1:] == [] or opt.attempt_history[1]["start"] == 1
    assert opt.best[1] > -0.1  # the second start point leads into the global basin
    # plain CMA-ES from the first start point stays in the local basin
    from besdrake.search.cmaes import CMAES

    plain = CMAES(starts[0], 0.5, np.random.default_rng(0), popsize=8, bounds=np.tile([-10.0, 10.0], (n, 1)))
    run(plain, 80)
    assert plain.best[1] < -0.4


def test_restart_from_best_and_generation_cap():
    n = 3
    opt = StagnationRestartCMAES(np.zeros((1, n)), 1.0, np.random.default_rng(1), popsize=6, stagnation_generations=50,
                                 max_generations=4, restart_from_best=True)
    run(opt, 12)
    assert [a["end"] for a in opt.attempt_history] == ["max_generations"] * 3
    assert [a["start"] for a in opt.attempt_history] == [0, -1, -1]
    assert opt.attempt == 3 and len(opt.attempt_best) == 0  # a fresh attempt, started at the best throw so far
    assert np.allclose(opt.inner.x0, opt.best[0])


def test_resumed_restart_optimizer_asks_the_same_candidates(tmp_path):
    n = 4
    kw = dict(popsize=6, bounds=np.tile([-10.0, 10.0], (n, 1)), stagnation_generations=3, tol=0.05)
    starts = np.array([[-3.0] * n, [1.0] * n])
    a = StagnationRestartCMAES(starts, 0.5, np.random.default_rng(7), **kw)
    run(a, 15)
    b = restored(a, tmp_path)
    assert b.attempt == a.attempt and b.attempt_best == a.attempt_best
    assert_same_asks(a, b, 25)
    assert a.attempt >= 2


def test_bad_restart_settings_are_rejected():
    with pytest.raises(ValueError):
        StagnationRestartCMAES(np.zeros((1, 3)), 1.0, np.random.default_rng(0), stagnation_generations=0)
    with pytest.raises(ValueError):
        StagnationRestartCMAES(np.full((1, 3), np.nan), 1.0, np.random.default_rng(0))
    with pytest.raises(ValueError):
        StagnationRestartCMAES(np.zeros((1, 3)), 1.0, np.random.default_rng(0), tol=-1.0)


def test_bipop_regimes_alternate_small_local_and_large_restarts():
    n = 4
    opt = StagnationRestartCMAES(np.zeros((1, n)), 1.0, np.random.default_rng(3), popsize=6, stagnation_generations=50,
                                 max_generations=3, restart_from_best=False, regimes="bipop", popsize_growth=2.0)
    told = 0
    for _ in range(3 * 6):
        X = opt.ask()
        opt.tell(X, two_basins(X))
        told += X.shape[0]
    hist = opt.attempt_history
    assert len(hist) >= 4 and hist[0]["regime"] == "large" and hist[0]["popsize"] == 6
    # the second attempt is small (no small episodes yet): from the best throw, a step below sigma0, same population
    assert hist[1]["regime"] == "small" and hist[1]["start"] == -1 and hist[1]["sigma0"] < 1.0 and hist[1]["popsize"] == 6
    for h in hist:  # large attempts restart from the start point (restart_from_best=False) and grow the population
        if h["regime"] == "large":
            assert h["sigma0"] == 1.0 and h["start"] == 0
    larges = [h["popsize"] for h in hist if h["regime"] == "large"]
    assert larges == [6 * 2**k for k in range(len(larges))]
    assert opt.evaluations["small"] + opt.evaluations["large"] == told


def test_resumed_bipop_restart_optimizer_asks_the_same_candidates(tmp_path):
    n = 4
    kw = dict(popsize=6, bounds=np.tile([-10.0, 10.0], (n, 1)), stagnation_generations=3, tol=0.05, regimes="bipop",
              popsize_growth=1.5, restart_from_best=True)
    a = StagnationRestartCMAES(np.full((1, n), -3.0), 0.5, np.random.default_rng(11), **kw)
    run(a, 12)
    b = restored(a, tmp_path)
    assert (b.regime, b.n_large_restarts, b.evaluations) == (a.regime, a.n_large_restarts, a.evaluations)
    assert_same_asks(a, b, 30)
    assert a.attempt >= 3
    assert {h["regime"] for h in a.attempt_history} == {"large", "small"}


def test_small_share_limits_the_episodes_of_small_restarts(tmp_path):
    n = 3
    opt = StagnationRestartCMAES(np.zeros((1, n)), 1.0, np.random.default_rng(5), popsize=6, stagnation_generations=50,
                                 max_generations=3, regimes="bipop", small_share=0.01)
    run(opt, 5 * 3)
    # one small restart (no small episodes yet), then large ones: the small share (1 %) is spent
    assert [h["regime"] for h in opt.attempt_history] == ["large", "small", "large", "large", "large"]
    save_state(opt.state_dict(), tmp_path / "opt")
    assert StagnationRestartCMAES.from_state(load_state(tmp_path / "opt")).small_share == 0.01


def drifting(step: float):
    """Rewards that move by ``step`` per generation (spread within a generation, so ``cma`` sees no flat fitness)."""
    generation = iter(range(10**6))

    def rewards(X: np.ndarray) -> np.ndarray:
        return step * next(generation) + 0.01 * np.arange(np.atleast_2d(X).shape[0])

    return rewards


def test_local_regimes_restart_small_until_stuck_then_once_large():
    n = 3
    opt = StagnationRestartCMAES(np.zeros((1, n)), 1.0, np.random.default_rng(4), popsize=6, stagnation_generations=50,
                                 max_generations=2, regimes="local", patience=2, tol=0.01)
    worse = drifting(-1.0)  # no attempt ever improves on the first generation's best
    for _ in range(7 * 2):
        X = opt.ask()
        opt.tell(X, worse(X))
    # nothing ever improves: the first (large) attempt, then 2 small ones (patience), one large, 2 small, ...
    assert [h["regime"] for h in opt.attempt_history] == ["large", "small", "small", "large", "small", "small", "large"]
    for h in opt.attempt_history[1:]:
        # small ones from the best throw with a smaller step; large ones from the start point (restart_from_best=False)
        assert (h["start"], h["sigma0"] == 1.0) == ((0, True) if h["regime"] == "large" else (-1, False))


def test_local_regimes_stay_small_while_the_small_restarts_improve():
    n = 3
    better = drifting(1.0)  # every generation better than the last
    opt = StagnationRestartCMAES(np.zeros((1, n)), 1.0, np.random.default_rng(4), popsize=6, stagnation_generations=50,
                                 max_generations=2, regimes="local", patience=1, tol=0.5)
    for _ in range(6 * 2):
        X = opt.ask()
        opt.tell(X, better(X))
    assert [h["regime"] for h in opt.attempt_history] == ["large"] + ["small"] * 5


def test_resumed_local_restart_optimizer_asks_the_same_candidates(tmp_path):
    n = 4
    kw = dict(popsize=6, bounds=np.tile([-10.0, 10.0], (n, 1)), stagnation_generations=3, tol=0.05, regimes="local", patience=1,
              restart_from_best=True)
    a = StagnationRestartCMAES(np.full((1, n), -3.0), 0.5, np.random.default_rng(11), **kw)
    run(a, 14)
    b = restored(a, tmp_path)
    assert (b.regime, b.small_streak, b.attempt_start_best, b.patience) == (a.regime, a.small_streak, a.attempt_start_best, 1)
    assert_same_asks(a, b, 40)
    assert a.attempt >= 3
    assert {h["regime"] for h in a.attempt_history} == {"large", "small"}


def test_scouts_run_one_after_the_other_and_the_best_goes_on():
    n = 3
    opt = StagnationRestartCMAES(np.zeros((1, n)), 1.0, np.random.default_rng(6), popsize=6, stagnation_generations=50,
                                 restart_from_best=True, regimes="bipop", scouts=3, scout_generations=4)
    inners, finals = [], []
    for _ in range(3 * 4):
        if not inners or inners[-1] is not opt.inner:
            inners.append(opt.inner)
        X = opt.ask()
        opt.tell(X, two_basins(X))
    hist = opt.attempt_history
    assert [(h["end"], h["generations"], h["start"]) for h in hist] == [("scout", 4, 0)] * 3  # each from the start point
    assert len(inners) == 3 and len({id(i) for i in inners}) == 3
    best = int(np.argmax([h["best_reward"] for h in hist]))
    assert opt.inner is inners[best] and opt.attempt == 3  # the best scout's CMA-ES goes on, with its history
    assert opt.attempt_best[-1] == hist[best]["best_reward"] and len(opt.attempt_best) == 4
    X = opt.ask()
    opt.tell(X, two_basins(X))
    assert len(opt.attempt_best) == 5 and opt.continued_scout == best
    while len(opt.attempt_history) == 3:  # the continued scout's record names the scout and its start point
        X = opt.ask()
        opt.tell(X, two_basins(X))
    assert opt.attempt_history[3]["continues_scout"] == best and opt.attempt_history[3]["start"] == 0
    assert all("continues_scout" not in h for h in opt.attempt_history[4:]) and opt.continued_scout is None


def test_resumed_scouting_asks_the_same_candidates(tmp_path):
    n = 4
    kw = dict(popsize=6, bounds=np.tile([-10.0, 10.0], (n, 1)), stagnation_generations=3, tol=0.05, regimes="bipop",
              restart_from_best=True, scouts=3, scout_generations=4)
    for told in (6, 10):  # mid-scouting, with a scout kept; and just before the best scout goes on
        a = StagnationRestartCMAES(np.full((1, n), -1.0), 0.5, np.random.default_rng(3), **kw)
        run(a, told)
        b = restored(a, tmp_path)
        assert b.kept_best == a.kept_best and (b.kept is None) == (a.kept is None) and b.kept_scout == a.kept_scout
        assert_same_asks(a, b, 40)
        assert a.attempt >= 5


def test_halving_races_the_scouts_and_the_better_half_goes_on():
    n = 3
    starts = np.array([[-3.0] * n, [3.0] * n, [0.0] * n, [-6.0] * n])  # the global optimum is at +3 (start 1)
    opt = StagnationRestartCMAES(starts, 0.5, np.random.default_rng(2), popsize=6, stagnation_generations=50,
                                 restart_from_best=True, regimes="bipop", scouts=4, scout_generations=3, scout_halving=True)
    inners = {}
    for _ in range(6 * 3):  # rung 0: 4 scouts x 3 generations; rung 1: the better 2 x 3 more
        inners.setdefault(id(opt.inner), opt.inner)
        assert opt.scouting()
        X = opt.ask()
        opt.tell(X, two_basins(X))
    hist = opt.attempt_history
    assert [(h["scout"], h["rung"], h["generations"], h["end"]) for h in hist[:4]] == [(k, 0, 3, "scout") for k in range(4)]
    assert [h["start"] for h in hist[:4]] == [0, 1, 2, 3]
    better = sorted(range(4), key=lambda k: -hist[k]["best_reward"])[:2]
    assert [(h["scout"], h["rung"], h["generations"]) for h in hist[4:6]] == [(k, 1, 6) for k in better]  # the better first
    assert len(inners) == 4  # rung 1 went on with the scouts' own CMA-ES, no new one
    winner = max(hist[4:6], key=lambda h: h["best_reward"])["scout"]
    assert 1 in better and not opt.scouting() and opt.continued_scout == winner
    assert len(opt.attempt_best) == 6 and opt.attempt_best[-1] == max(h["best_reward"] for h in hist[4:6])
    X = opt.ask()
    opt.tell(X, two_basins(X))
    assert opt.inner is not None and len(opt.attempt_best) == 7


def test_halving_drops_stalled_scouts_and_resumes_anywhere(tmp_path):
    n = 4
    kw = dict(popsize=6, bounds=np.tile([-10.0, 10.0], (n, 1)), stagnation_generations=3, tol=0.05, regimes="bipop",
              restart_from_best=True, scouts=4, scout_generations=4, scout_halving=True)
    starts = np.array([[-1.0] * n, [2.0] * n, [-3.0] * n, [1.0] * n])
    a = StagnationRestartCMAES(starts, 0.5, np.random.default_rng(5), **kw)
    run(a, 60)
    scout_ends = [h for h in a.attempt_history if "rung" in h]
    stalled = {h["scout"]: h["rung"] for h in scout_ends if h["end"] != "scout"}
    assert stalled  # (this seed: scouts stall, the race goes on without them)
    for h in scout_ends:
        assert h["rung"] <= stalled.get(h["scout"], h["rung"])  # a scout that stalled does not race on
    for told in (3, 9, 17, 21):  # rung 0, rung 0 with scouts filed, rung 1, about the hand-over
        a = StagnationRestartCMAES(starts, 0.5, np.random.default_rng(5), **kw)
        run(a, told)
        b = restored(a, tmp_path)
        assert (b.rung, b.current_scout, [k for k, _, _ in b.rung_queue]) == (a.rung, a.current_scout, [k for k, _, _ in a.rung_queue])
        assert_same_asks(a, b, 30)


def test_scouting_episodes_counts_every_rung():
    from besdrake.search.refinement import scouting_episodes

    assert scouting_episodes(10, scouts=4, scout_generations=12, scout_halving=False) == 480  # 4 scouts one after the other
    assert scouting_episodes(10, scouts=4, scout_generations=4, scout_halving=True) == (4 + 2) * 4 * 10
    assert scouting_episodes(10, scouts=5, scout_generations=4, scout_halving=True) == (5 + 3 + 2) * 4 * 10
    assert scouting_episodes(20, scouts=1, scout_generations=4, scout_halving=True) == 0  # no race with one scout
    # The default race (session 34): four scouts in rungs of 3 generations of 10 cost 180 episodes (240 in rungs of 4).
    assert scouting_episodes(10) == (4 + 2) * 3 * 10
    with pytest.raises(RefinementError):
        scouting_episodes(10, scouts=-1)


def test_bad_regime_settings_are_rejected():
    for kw in ({"regimes": "ipop"}, {"popsize_growth": 0.5}, {"small_decades": -1.0}, {"small_share": 0.0},
               {"regimes": "local", "patience": 0}, {"regimes": "local", "patience": 1.5}, {"scouts": -1}, {"scout_generations": 0}):
        with pytest.raises(ValueError):
            StagnationRestartCMAES(np.zeros((1, 3)), 1.0, np.random.default_rng(0), **kw)


@pytest.fixture(scope="module")
def base():
    return fitted_default_throw()


def test_rank_starts_and_restart_points(base):
    near, far = base.copy(), base.copy()
    far.goal = far.goal.copy()
    far.goal[1] += 0.5  # StandIn: lands 0.5 m farther out (beyond the target)
    near.goal = near.goal.copy()
    near.goal[1] += 0.8  # lands 0.8 m out: closest to the target 2 m (StandIn x = goal of joint 2 + 1)
    problems = [RefinementProblem(COMPI, b, retime=False) for b in (base, far, near)]  # the mapping itself, unretimed
    ranked = rank_starts(problems, StandIn())
    rewards = [r.reward for _, r in ranked]
    assert rewards == sorted(rewards, reverse=True)
    # the closest throw breaks a limit (goal of joint 2 + 0.8 rad): the limit offset ranks it last
    assert [i for i, _ in ranked] == [1, 0, 2] and ranked[2][1].penalty >= ThrowReward().violation_offset
    assert ranked[2][1].distance < ranked[0][1].distance
    pts = restart_points(problems[0], [problems[i] for i, _ in ranked])
    assert pts.shape == (3, problems[0].n_params)
    for row, (i, _) in zip(pts, ranked):
        assert np.allclose(problems[0].theta(row), problems[i].scaling.theta0)
    assert np.allclose(pts[1], 0.0)  # problem 0's own throw (second in the ranking) is its origin


def test_refine_with_restarts_succeeds_records_attempts_and_resumes(base, tmp_path):
    problem = RefinementProblem(COMPI, base)
    kw = dict(seed=0, popsize=8, stagnation_generations=3, stagnation_tol=0.01, stop_on_success=False, starts=np.zeros((2, 49)))
    first = refine(problem, StandIn(), n_episodes=48, out_dir=tmp_path, **kw)
    again = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=400, out_dir=tmp_path, **kw)
    assert again.resumed and again.n_episodes == 400
    fresh = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=400, **kw)
    assert np.array_equal(fresh.rewards, again.rewards)  # resuming changes nothing
    assert fresh.attempts == again.attempts
    assert first.n_episodes == 48
    assert np.nanmin(fresh.best_so_far()) < 0.1
    with pytest.raises(RefinementError, match="another refinement"):
        refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=480, out_dir=tmp_path, **(kw | {"stagnation_generations": 4}))
    with pytest.raises(RefinementError, match="columns"):
        refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=8, **(kw | {"starts": np.zeros((2, 3))}))


def test_default_bipop_refine_resumes_and_rejects_a_folder_of_the_previous_default(base, tmp_path):
    from besdrake.search.refinement import DEFAULT_RESTART_REGIMES

    assert DEFAULT_RESTART_REGIMES == "bipop"
    kw = dict(seed=1, popsize=6, stagnation_generations=2, stagnation_tol=0.5, stop_on_success=False)
    refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=30, out_dir=tmp_path / "new", **kw)
    again = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=120, out_dir=tmp_path / "new", **kw)
    fresh = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=120, **kw)
    assert again.resumed and np.array_equal(fresh.rewards, again.rewards) and fresh.attempts == again.attempts
    assert {a["regime"] for a in fresh.attempts} == {"large", "small"}
    small = [a for a in fresh.attempts if a["regime"] == "small"]
    assert all(a["start"] == -1 and a["sigma0"] <= 1.0 for a in small)
    # a run folder of the previous default (every restart large) is another run
    refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=12, out_dir=tmp_path / "old", restart_regimes="large", **kw)
    with pytest.raises(RefinementError, match="another refinement"):
        refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=24, out_dir=tmp_path / "old", **kw)
    with pytest.raises(RefinementError, match="restart_regimes"):
        refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=12, restart_regimes="ipop", **kw)


@pytest.mark.parametrize("options", [{"CMA_diagonal": True}, {"CMA_elitist": True}, {"CMA_diagonal": True, "CMA_elitist": True}])
def test_separable_and_elitist_cmaes_resume_with_the_same_candidates(tmp_path, options):
    from besdrake.search.cmaes import CMAES

    n = 6
    a = CMAES(np.zeros(n), 1.0, np.random.default_rng(2), popsize=6, bounds=np.tile([-10.0, 10.0], (n, 1)), cma_options=options)
    run(a, 12)
    save_state(a.state_dict(), tmp_path / "opt")
    b = CMAES.from_state(load_state(tmp_path / "opt"))
    for _ in range(20):
        Xa, Xb = a.ask(), b.ask()
        assert np.array_equal(Xa, Xb)
        a.tell(Xa, two_basins(Xa))
        b.tell(Xb, two_basins(Xb))
    if options.get("CMA_diagonal"):
        assert not hasattr(a.es.sm, "C")  # really the separable variant


def test_cli_search_options_map_to_refine_keywords():
    import argparse

    from besdrake.commands.refine import add_arguments, search_options
    from besdrake.search.refinement import DEFAULT_CMA_OPTIONS, DEFAULT_STAGNATION_GENERATIONS, PLAIN_SEARCH

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    default = search_options(parser.parse_args(["x"]))
    assert default["cma_options"] == {k: v for k, v in DEFAULT_CMA_OPTIONS.items() if v}
    assert default["stagnation_generations"] == DEFAULT_STAGNATION_GENERATIONS and default["restart_from_best"]
    assert search_options(parser.parse_args(["x", "--plain", "--separable", "--stagnation", "5"])) == PLAIN_SEARCH
    custom = search_options(parser.parse_args(["x", "--separable", "--no-elitist", "--stagnation", "7", "--restart-from", "start"]))
    assert custom == {"cma_options": {"CMA_diagonal": True}, "stagnation_generations": 7, "restart_from_best": False}
    assert search_options(parser.parse_args(["x", "--meta-episodes", "50"]))["stagnation_generations"] == 0
    regimes = search_options(parser.parse_args(["x", "--regimes", "large", "--popsize-growth", "2"]))
    assert regimes["restart_regimes"] == "large" and regimes["popsize_growth"] == 2.0
    local = search_options(parser.parse_args(["x", "--regimes", "local", "--patience", "3", "--scouts", "0", "--scout-generations", "5"]))
    assert (local["restart_regimes"], local["patience"], local["scouts"], local["scout_generations"]) == ("local", 3, 0, 5)
    assert "scouts" not in default and "patience" not in default and "scout_halving" not in default  # the module's defaults apply
    assert search_options(parser.parse_args(["x", "--no-scout-halving"]))["scout_halving"] is False


def test_scouting_refine_resumes_and_a_default_run_is_another_run(base, tmp_path):
    kw = dict(seed=2, popsize=6, stagnation_generations=50, stop_on_success=False, scout_generations=3)
    n = (3 * 3 + 4) * 6
    refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=30, out_dir=tmp_path / "scouts", scouts=3, **kw)
    again = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=n, out_dir=tmp_path / "scouts", scouts=3, **kw)
    fresh = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=n, scouts=3, **kw)
    assert again.resumed and np.array_equal(fresh.rewards, again.rewards) and fresh.attempts == again.attempts
    assert [(a["end"], a["generations"], a["start"]) for a in fresh.attempts[:3]] == [("scout", 3, 0)] * 3
    # without scouts no attempt is a scout; the default (DEFAULT_SCOUTS scouts) is another run than three scouts
    unscouted = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=n, scouts=0, **kw)
    assert all(a["end"] != "scout" for a in unscouted.attempts)
    default = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=n, **kw)
    assert [a["end"] for a in default.attempts[:DEFAULT_SCOUTS]] == ["scout"] * DEFAULT_SCOUTS
    with pytest.raises(RefinementError, match="another refinement"):
        refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=n + 6, out_dir=tmp_path / "scouts", **kw)
    for bad in ({"scouts": -1}, {"scout_generations": 0}, {"patience": 0}):
        with pytest.raises(RefinementError):
            refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=12, **(kw | bad))


def test_a_run_begun_with_another_race_resumes_with_its_own(base, tmp_path):
    """A run folder begun with rungs of 4 generations (the default until session 34) resumes under the new default with
    its own race: the same episodes as the uninterrupted run, not "another refinement run"."""
    kw = dict(seed=3, popsize=6, stagnation_generations=50, stop_on_success=False, scouts=3)
    n = (3 + 2) * 4 * 6 + 12
    refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=30, out_dir=tmp_path / "old", scout_generations=4, **kw)
    again = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=n, out_dir=tmp_path / "old", **kw)
    whole = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=n, scout_generations=4, **kw)
    assert again.resumed and np.array_equal(whole.rewards, again.rewards)
    assert [a["generations"] for a in again.attempts[:3]] == [4, 4, 4]
    # a new folder takes the default, and an explicit rung length that differs from the record is refused
    fresh = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=n, out_dir=tmp_path / "new", **kw)
    assert [a["generations"] for a in fresh.attempts[:3]] == [DEFAULT_SCOUT_GENERATIONS] * 3
    with pytest.raises(RefinementError, match="another refinement"):
        refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=n + 6, out_dir=tmp_path / "old", scout_generations=3, **kw)


def test_default_step_is_the_measured_sigma0_and_small_restarts_scale_with_it(base):
    """The scouts and large restarts start with DEFAULT_SIGMA0, the small restarts below it; an explicit sigma0 rules."""
    from besdrake.search.refinement import DEFAULT_SIGMA0

    assert 0.0 < DEFAULT_SIGMA0 <= 1.0
    kw = dict(seed=1, popsize=6, stagnation_generations=2, stagnation_tol=0.5, stop_on_success=False, scout_generations=2)
    default = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=150, **kw)
    large = [a for a in default.attempts if a["regime"] == "large"]
    small = [a for a in default.attempts if a["regime"] == "small"]
    assert large and small, default.attempts
    assert all(a["sigma0"] == DEFAULT_SIGMA0 for a in large)
    assert all(a["sigma0"] < DEFAULT_SIGMA0 for a in small)
    other = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=60, sigma0=0.4, **kw)
    assert all(a["sigma0"] == 0.4 for a in other.attempts if a["regime"] == "large")


def test_meta_stage_and_restarts_do_not_combine(base):
    with pytest.raises(RefinementError, match="do not combine"):
        refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=8, meta_episodes=4, stagnation_generations=3)


@pytest.mark.slow
def test_default_search_brings_an_imitated_throw_close_to_the_target(tmp_path):
    """Synthetic subject 2, the default search (separable elitist CMA-ES with restarts), 300 episodes."""
    import logging

    from besdrake.commands.refine import collect_imitated
    from besdrake.imitation import load_dmp
    from besdrake.search.refinement import best_start
    from besdrake.sim import make_executor

    logging.getLogger("drake").setLevel(logging.ERROR)
    problems = [RefinementProblem(COMPI, load_dmp(f)) for f in collect_imitated(["synthetic:2"], tmp_path)]
    with make_executor("serial") as ex:
        index, start = best_start(problems, ex)
        result = refine(problems[index], ex, n_episodes=300, seed=0, out_dir=tmp_path / "run")
    best = np.nanmin(result.best_so_far())
    assert best < 0.5 * start.distance, (start.distance, result.summary())
    assert result.success or best < 0.3, result.summary()


@pytest.mark.slow
def test_bipop_small_restart_refines_a_near_miss(tmp_path):
    """Synthetic subject 5, seed 1: every-restart-large stalled at 0.102 m for 1300 episodes; BIPOP (the default
    before session 6: no scouts, no retiming, 0.2 m limit offset) reached the goal after 221 episodes in the
    screening, through a small restart from the best throw."""
    import logging

    from besdrake.commands.refine import collect_imitated
    from besdrake.imitation import load_dmp
    from besdrake.search.refinement import best_start
    from besdrake.sim import make_executor

    logging.getLogger("drake").setLevel(logging.ERROR)
    problems = [RefinementProblem(COMPI, load_dmp(f), ThrowReward(violation_offset=0.2), retime=False)
                for f in collect_imitated(["synthetic:5"], tmp_path)]
    with make_executor("serial") as ex:
        index, _ = best_start(problems, ex)
        result = refine(problems[index], ex, n_episodes=500, seed=1, scouts=0, sigma0=1.0)  # the step of that screening
    assert result.success, result.summary()
    if not result.attempts:  # session 27's machine: the first attempt reaches the goal (82 episodes), no restart to check
        return
    # where the first (large) attempt stalled, the goal came in a later attempt, and the next after the first is small
    first = result.attempts[0]
    assert first["regime"] == "large" and first["end"] == "stagnation", result.attempts
    assert result.episodes_to_success > first["generations"] * first["popsize"], (result.episodes_to_success, result.attempts)
    assert len(result.attempts) == 1 or result.attempts[1]["regime"] == "small", result.attempts


def test_scout_start_points_are_the_best_imitated_throws_in_order(base):
    far, near = base.copy(), base.copy()
    far.goal = far.goal.copy()
    far.goal[1] -= 0.5
    near.goal = near.goal.copy()
    near.goal[1] += 0.8
    problems = [RefinementProblem(COMPI, b, retime=False) for b in (base, far, near)]
    ranked = rank_starts(problems, StandIn())
    assert scout_start_points(problems, ranked, 1) is None  # every scout from the start throw
    pts = scout_start_points(problems, ranked, 2)
    assert pts.shape == (2, problems[0].n_params)
    best = problems[ranked[0][0]]
    assert np.allclose(pts[0], 0.0)  # the start throw itself first
    assert np.allclose(best.theta(pts[1]), problems[ranked[1][0]].scaling.theta0)
    assert scout_start_points(problems, ranked, 10).shape[0] == 3  # no more than there are throws
    with pytest.raises(RefinementError):
        scout_start_points(problems, ranked, 0)


def test_later_runs_start_from_the_next_throws_in_the_ranking():
    order = [7, 3, 9, 1, 0, 4, 8, 2, 6, 5]
    assert run_start_order(order, 0) == order  # the first run: the best four as before
    assert run_start_order(order, 1)[:4] == [0, 4, 8, 2]  # the next four, the fifth best first
    assert run_start_order(order, 2, n=4)[:4] == [6, 5, 7, 3]  # wraps around when the throws run out
    assert sorted(run_start_order(order, 5, n=3)) == sorted(order)  # a rotation: no throw lost or repeated
    assert run_start_order([4, 2], 1, n=1) == [2, 4]
    with pytest.raises(RefinementError):
        run_start_order([], 1)
    with pytest.raises(RefinementError):
        run_start_order(order, 1, n=0)


@pytest.mark.slow
def test_default_search_reaches_the_goal_where_bipop_alone_stalled(tmp_path):
    """Synthetic subject 0, seed 0: BIPOP alone stalled at 0.109 m after 1500 episodes (a throw family that lands
    short); the default -- scouts from the four best imitated throws raced by successive halving, retiming, 1 m limit
    offset -- reached the goal after 1046 episodes in the benchmark (the scouts one after the other: 678). ~1-2 minutes."""
    import logging

    from besdrake.commands.refine import collect_imitated
    from besdrake.imitation import load_dmp
    from besdrake.sim import make_executor

    logging.getLogger("drake").setLevel(logging.ERROR)
    problems = [RefinementProblem(COMPI, load_dmp(f)) for f in collect_imitated(["synthetic:0"], tmp_path)]
    with make_executor("serial") as ex:
        ranking = rank_starts(problems, ex)
        index = ranking[0][0]
        result = refine(problems[index], ex, n_episodes=1100, seed=0, starts=scout_start_points(problems, ranking))
    assert result.success, result.summary()
    assert [a["end"] for a in result.attempts[:DEFAULT_SCOUTS]] == ["scout"] * DEFAULT_SCOUTS
    assert {a["start"] for a in result.attempts[:DEFAULT_SCOUTS]} == set(range(DEFAULT_SCOUTS))  # one per imitated throw


def _six_throws(base, folder):
    """Six imitated stand-in throws (``base`` with its joint-2 goal moved) saved in ``folder``."""
    from besdrake.imitation import save_dmp

    folder.mkdir()
    for k, dz in enumerate((0.0, -0.2, 0.2, -0.4, 0.4, -0.6)):
        throw = base.copy()
        throw.goal = throw.goal.copy()
        throw.goal[1] += dz
        save_dmp(throw, folder / f"throw{k}.dmp.json")
    return folder


def test_refine_command_runs_scout_from_different_throws(base, tmp_path):
    """``besdrake refine --runs 2`` (``--run-starts diverse``, the default): run 1 starts from the fifth-best of six
    imitated throws; ``--run-starts same`` starts both from the best."""
    import json

    from besdrake.cli import main

    folder = _six_throws(base, tmp_path / "imitated")
    picks = {}
    for how in ("diverse", "same"):
        out = tmp_path / how
        argv = ["refine", str(folder), "--out", str(out), "--episodes", "4", "--popsize", "4", "--runs", "2",
                "--run-starts", how, "--quiet", "--json", "--no-figures", "--backend", "serial"]
        assert main(argv) == 0
        summary = json.loads((out / "summary.json").read_text())
        picks[how] = summary["start"]["run_start_throws"]
        assert [r["n_episodes"] for r in summary["runs"]] == [4, 4]
    ranking = json.loads((tmp_path / "same" / "start.json").read_text())["ranking"]
    assert picks["same"] == [ranking[0], ranking[0]]
    assert picks["diverse"] == [ranking[0], ranking[4]]


def _switching(switch_below, seed: int = 0):
    """Two raced scouts on the two-basin function: scout 0 starts on the broad local optimum (it leads the race),
    scout 1 on the way to the global one (it is eliminated)."""
    n = 3
    starts = np.array([[-3.0] * n, [1.5] * n])
    return StagnationRestartCMAES(starts, 0.5, np.random.default_rng(seed), popsize=6, bounds=np.tile([-10.0, 10.0], (n, 1)),
                                  stagnation_generations=5, tol=0.01, restart_from_best=True, regimes="bipop", scouts=2,
                                  scout_generations=3, scout_halving=True, switch_below=switch_below)


def test_a_winner_that_stalls_far_hands_over_to_the_scout_the_race_eliminated():
    on, off = _switching(-0.2), _switching(None)
    run(on, 60)
    run(off, 60)
    race = [h["scout"] for h in on.attempt_history if "rung" in h]
    assert race == [0, 1]  # one rung decides two scouts
    continued = [h.get("continues_scout") for h in on.attempt_history if "rung" not in h]
    assert continued[:2] == [0, 1]  # the winner stalled near -0.5, below -0.2: the eliminated scout went on
    first = next(h for h in on.attempt_history if h.get("continues_scout") == 0)
    assert first["best_reward"] < -0.2 and first["end"] != "scout"
    assert on._best_reward > -0.1  # ... and found the global basin the winner never reached
    assert all(h.get("continues_scout") != 1 for h in off.attempt_history)  # without the switch: restarts from the best
    assert off._best_reward < -0.4 and not off.reserve
    assert on.attempt_history[:3] == off.attempt_history[:3]  # the same run up to the switch


def test_a_switching_run_resumes_anywhere(tmp_path):
    for told in (2, 5, 12, 20):  # racing, the winner going on, about the hand-over, after it
        a = _switching(-0.2)
        run(a, told)
        b = restored(a, tmp_path)
        assert b.switch_below == -0.2 and [k for k, _, _ in b.reserve] == [k for k, _, _ in a.reserve]
        assert_same_asks(a, b, 30)


def test_switch_distance_needs_raced_scouts_and_a_distance(base):
    from besdrake.search.refinement import make_optimizer

    problem = RefinementProblem(COMPI, base)
    assert make_optimizer(problem, switch_distance=0.3).switch_below == -0.3
    assert make_optimizer(problem).switch_below is None
    for bad in (0.0, -0.3, float("nan")):
        with pytest.raises(RefinementError, match="switch_distance"):
            make_optimizer(problem, switch_distance=bad)
    with pytest.raises(RefinementError, match="raced scouts"):
        make_optimizer(problem, switch_distance=0.3, scouts=0)
    with pytest.raises(ValueError, match="switch_below"):
        StagnationRestartCMAES(np.zeros((1, 2)), 0.5, np.random.default_rng(0), switch_below=float("inf"))


@pytest.mark.parametrize("far, ends_after", [(-2.0, 5), (-0.45, 10)])
def test_a_family_switched_to_that_stays_behind_the_runs_best_ends(far, ends_after):
    """A plateau of -0.3 about -3 (the race's winner stalls there); about +10 a family that climbs for long towards
    ``far`` but never reaches -0.3: more than twice as far it ends after half the stagnation window, else after it."""
    def landscape(X):
        X = np.atleast_2d(X)
        return np.maximum(-0.3 - 0.01 * np.sum((X + 3.0) ** 2, axis=1), far - 0.001 * np.sum((X - 10.0) ** 2, axis=1))

    n = 3
    opt = StagnationRestartCMAES(np.array([[-3.0] * n, [3.0] * n]), 0.5, np.random.default_rng(1), popsize=6,
                                 bounds=np.tile([-20.0, 20.0], (n, 1)), stagnation_generations=10, tol=1e-4,
                                 restart_from_best=True, regimes="bipop", scouts=2, scout_generations=3, scout_halving=True,
                                 switch_below=-0.2)
    for _ in range(60):
        X = opt.ask()
        opt.tell(X, landscape(X))
    switched = next(h for h in opt.attempt_history if h.get("continues_scout") == 1)
    assert switched["end"] == "behind" and switched["generations"] == 3 + ends_after and switched["best_reward"] < -0.3
    after = opt.attempt_history[opt.attempt_history.index(switched) + 1:]
    assert after and all(h["start"] == -1 for h in after)  # no family left: restarts from the run's best again


def _racing(next_starts, seed: int = 0):
    """Two raced scouts that both start in the broad local optimum of the two-basin function (every family of the first
    race stalls near -0.5, below the switch at -0.2); ``next_starts``: the start points of a second race."""
    n = 3
    starts = np.array([[-3.0] * n, [-3.5] * n])
    return StagnationRestartCMAES(starts, 0.5, np.random.default_rng(seed), popsize=6, bounds=np.tile([-10.0, 10.0], (n, 1)),
                                  stagnation_generations=5, tol=0.01, restart_from_best=True, regimes="bipop", scouts=2,
                                  scout_generations=3, scout_halving=True, switch_below=-0.2, next_starts=next_starts)


def test_a_run_whose_raced_families_all_fall_short_races_the_next_start_points():
    n = 3
    on, off = _racing(np.array([[2.5] * n, [-1.0] * n])), _racing(None)
    run(on, 80)
    run(off, 80)
    scouts = [h["scout"] for h in on.attempt_history if "rung" in h]
    assert scouts == [0, 1, 2, 3] and on.race == 1  # a second race of two scouts
    second = on.attempt_history.index(next(h for h in on.attempt_history if h.get("scout") == 2))
    before = on.attempt_history[:second]
    assert [h.get("continues_scout") for h in before if "rung" not in h] == [0]  # the winner ended short of the switch
    assert all(h["best_reward"] < -0.2 for h in before)  # ... and the next race came before the eliminated scout
    assert [h["start"] for h in on.attempt_history if h.get("scout") in (2, 3)] == [2, 3]  # rows after ``starts``
    assert on._best_reward > -0.1 and off._best_reward < -0.4  # the second race found the global basin
    assert on.attempt_history[:second] == off.attempt_history[:second]  # the same run up to the second race


def test_a_racing_run_resumes_anywhere(tmp_path):
    n = 3
    for told in (5, 15, 25, 40):  # first race, its families ending, the second race, after it
        a = _racing(np.array([[2.5] * n, [-1.0] * n]))
        run(a, told)
        b = restored(a, tmp_path)
        assert b.race == a.race and np.array_equal(b.next_starts, a.next_starts)
        assert_same_asks(a, b, 30)


def test_further_races_need_a_switch_and_matching_start_points(base):
    from besdrake.search.refinement import make_optimizer

    problem = RefinementProblem(COMPI, base)
    nxt = np.zeros((4, problem.n_params))
    assert make_optimizer(problem, switch_distance=0.3, next_starts=nxt).n_races() == 2
    with pytest.raises(RefinementError, match="next_starts"):
        make_optimizer(problem, next_starts=nxt)
    with pytest.raises(ValueError, match="next_starts"):
        _racing(np.zeros((2, 4)))  # three parameters, not four
    with pytest.raises(ValueError, match="next_starts"):
        StagnationRestartCMAES(np.zeros((2, 3)), 0.5, np.random.default_rng(0), scouts=2, scout_halving=True, next_starts=np.zeros((2, 3)))


def test_race_points_are_the_next_groups_of_the_runs_order(base):
    from besdrake.search.refinement import race_points

    throws = []
    for k in range(10):
        t = base.copy()
        t.goal = t.goal.copy()
        t.goal[1] += 0.05 * k
        throws.append(t)
    problems = [RefinementProblem(COMPI, t) for t in throws]
    order = list(range(9, -1, -1))  # best first: throw 9
    pts = race_points(problems, order, 0, 2, 4)
    assert np.allclose(pts, restart_points(problems[9], [problems[i] for i in (5, 4, 3, 2)]))
    later = race_points(problems, order, 2, 2, 4)  # group 2 starts at throw 1 (throws 1, 0, 9, 8 wrapping around)
    assert np.allclose(later, restart_points(problems[1], [problems[i] for i in (7, 6, 5, 4)]))
    assert race_points(problems, order, 0, 1, 4) is None and race_points(problems, order[:4], 0, 2, 4) is None
    with pytest.raises(RefinementError, match="races"):
        race_points(problems, order, 0, 0, 4)


def test_after_the_last_race_the_eliminated_scouts_of_every_race_are_switched_to():
    n = 3
    opt = _racing(np.array([[-2.5] * n, [-4.0] * n]))  # the second race starts in the local optimum too
    run(opt, 80)
    continued = [h["continues_scout"] for h in opt.attempt_history if "continues_scout" in h]
    assert opt.race == 1 and continued[0] == 0  # the first race's winner, then the second race
    winner = continued[1]
    assert winner in (2, 3) and continued[2:4] == [5 - winner, 1]  # the second race's runner-up first, then the first's
    assert opt._best_reward < -0.4


def test_refine_command_gives_each_run_its_further_races(base, tmp_path):
    """``besdrake refine --races 2 --switch-distance 0.3``: run 0 races the throws ranked 1-4 and may race 5-8 (here
    six throws: 5, 6, 1, 2), run 1 starts from the ninth (wrapping: the third); without a switch it is refused."""
    import json

    from besdrake.cli import main

    folder = _six_throws(base, tmp_path / "imitated")
    out = tmp_path / "out"
    argv = ["refine", str(folder), "--out", str(out), "--episodes", "4", "--popsize", "4", "--runs", "2", "--quiet",
            "--no-figures", "--backend", "serial", "--races", "2"]
    assert main(argv) == 2  # refused: no --switch-distance
    assert main(argv + ["--switch-distance", "0.3", "--json"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    ranking = json.loads((out / "start.json").read_text())["ranking"]
    assert summary["start"]["run_start_throws"] == [ranking[0], ranking[2]]
    record = json.loads((out / "run0" / "problem.json").read_text())
    assert len(record["next_starts"]) == 4 and record["switch_distance"] == 0.3 and "race_stall" not in record
    assert main(argv[:-2] + ["--switch-distance", "0.3", "--race-stall-episodes", "200"]) == 2  # refused: one race only
    stalls = tmp_path / "stalls"
    assert main([*argv[:3], str(stalls), *argv[4:], "--switch-distance", "0.3", "--race-stall-episodes", "200"]) == 0
    record = json.loads((stalls / "run0" / "problem.json").read_text())
    assert record["race_stall"] == {"episodes": 200, "tol": 0.01, "after": 400, "beyond": 0.1}


def near_miss(X: np.ndarray) -> np.ndarray:
    """A local optimum at -3 that stops 0.15 short of the goal (closer than a 0.3 switch: its winner never ends far) and
    the global one (0) at +3."""
    X = np.atleast_2d(X)
    return -np.minimum(np.sum((X - 3.0) ** 2, axis=1), 0.15 + 0.1 * np.sum((X + 3.0) ** 2, axis=1))


def _near_racing(race_stall, seed: int = 0):
    """Two raced scouts in the near miss's local optimum, a second group of start points (one of them at the global one)
    and, with ``race_stall``, the next race where the current one stalls short of -0.1."""
    from besdrake.search.cmaes import RaceStall

    n = 3
    rule = None if race_stall is None else RaceStall(*race_stall)
    return StagnationRestartCMAES(np.array([[-3.0] * n, [-3.5] * n]), 0.5, np.random.default_rng(seed), popsize=6,
                                  bounds=np.tile([-10.0, 10.0], (n, 1)), stagnation_generations=5, tol=0.01, restart_from_best=True,
                                  regimes="bipop", scouts=2, scout_generations=3, scout_halving=True, switch_below=-0.3,
                                  next_starts=np.array([[2.5] * n, [-1.0] * n]), race_stall=rule)


def run_near(opt, generations: int) -> None:
    for _ in range(generations):
        X = opt.ask()
        opt.tell(X, near_miss(X))


def test_a_race_that_stalls_short_of_the_goal_races_the_next_start_points():
    """The winner stalls at -0.15, inside the switch distance: without ``race_stall`` the run creeps there for good;
    with it (8 generations, 0.01, below -0.1) the second race runs and finds the goal."""
    on, off = _near_racing((8, 0.01, -0.1)), _near_racing(None)
    run_near(on, 80)
    run_near(off, 80)
    assert off.race == 0 and -0.2 < off._best_reward < -0.14  # stuck short of the goal (and never far enough to switch)
    assert on.race == 1 and on._best_reward > -0.1
    stalled = next(i for i, h in enumerate(on.attempt_history) if h["end"] == "race_stall")
    assert [h.get("scout") for h in on.attempt_history[stalled + 1:stalled + 3]] == [2, 3]  # the next race's scouts
    assert on.attempt_history[:stalled] == off.attempt_history[:stalled]  # the same run up to the stall
    assert on.race_start_episode() == on.race_episode > 0 and off.race_start_episode() == 0


def test_a_race_stall_waits_for_its_goal_its_window_and_its_start():
    from besdrake.search.cmaes import RaceStall

    rule = RaceStall(generations=3, tol=0.01, below=-0.1, after=5)
    assert not rule.stalled([-0.2] * 4) and rule.stalled([-0.2] * 5) and not rule.stalled([-0.3, -0.3, -0.25, -0.2, -0.2])
    reached = _near_racing((2, 10.0, -0.5))  # the run's best passes -0.5 within the first race: never races on
    run_near(reached, 60)
    assert reached.race == 0
    for bad in ({"generations": 0}, {"after": -1}, {"tol": -0.1}, {"below": float("nan")}):
        with pytest.raises(ValueError, match="race_stall"):
            RaceStall(**({"generations": 3, "tol": 0.01, "below": -0.1} | bad))
    with pytest.raises(ValueError, match="race_stall needs next_starts"):
        StagnationRestartCMAES(np.zeros((2, 3)), 0.5, np.random.default_rng(0), scouts=2, scout_halving=True, switch_below=-0.3,
                               race_stall=RaceStall(3, 0.01, -0.1))


def test_a_run_racing_on_stalls_resumes_anywhere(tmp_path):
    for told in (5, 20, 30, 45):  # first race, about its stall, the second race, after it
        a = _near_racing((8, 0.01, -0.1))
        run_near(a, told)
        b = restored(a, tmp_path)
        assert b.race_stall == a.race_stall and b.race_best == a.race_best and b.race_episode == a.race_episode
        for _ in range(30):
            Xa, Xb = a.ask(), b.ask()
            assert np.array_equal(Xa, Xb)
            a.tell(Xa, near_miss(Xa))
            b.tell(Xb, near_miss(Xb))
        assert a.attempt_history == b.attempt_history


def test_refine_races_on_a_stall_and_its_stall_rule_judges_the_race_alone(base, tmp_path):
    """refine(race_stall=): a run that stalls races its next group; the run's own stall rule then counts from that race's
    start (it ends the run 24 episodes into the second race, not at once), and a killed run resumes to the same end."""
    from besdrake.search.refinement import StallRule
    from tests.test_refinement import StandIn

    problem = RefinementProblem(COMPI, base)
    always = StallRule(episodes=16, tol=10.0, after=24)  # stalled as soon as 24 episodes are judged
    kw = dict(seed=3, popsize=8, stop_on_success=False, scouts=2, scout_generations=1, starts=np.zeros((2, problem.n_params)),
              switch_distance=0.3, next_starts=np.zeros((2, problem.n_params)), stall=always)
    plain = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=200, **kw)
    assert plain.n_episodes == 24 and plain.stop_reason == "stalled"
    rule = StallRule(episodes=16, tol=10.0, after=0, beyond=0.0)
    raced = refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=200, race_stall=rule, **kw)
    assert [a["end"] for a in raced.attempts][:3] == ["scout", "scout", "race_stall"]  # the winner's third generation
    assert raced.n_episodes == 24 + 24 and raced.stop_reason == "stalled"
    refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=32, out_dir=tmp_path, race_stall=rule, **kw)
    ex = StandIn()
    resumed = refine(RefinementProblem(COMPI, base), ex, n_episodes=200, out_dir=tmp_path, race_stall=rule, **kw)
    assert resumed.resumed and np.array_equal(resumed.rewards, raced.rewards) and resumed.stop_reason == "stalled"
    ex = StandIn()
    again = refine(RefinementProblem(COMPI, base), ex, n_episodes=200, out_dir=tmp_path, race_stall=rule, **kw)
    assert again.n_episodes == 48 and ex.calls == 0  # a stalled run stays stopped, judged from its last race
    with pytest.raises(RefinementError, match="race_stall"):
        refine(RefinementProblem(COMPI, base), StandIn(), n_episodes=50, race_stall=rule, **{**kw, "next_starts": None})

