"""Independent jobs on one executor (besdrake.sim.scheduler): one wider batch per round, the results of running
them one after the other, resumable refinement runs."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from besdrake.plan import PlanError
from besdrake.sim.executors import ExecutorStats
from besdrake.sim.scheduler import run_concurrently


class FakeExecutor:
    """Outcome of a 'plan' (a number) is a deterministic function of it; records each call's width and thread."""

    def __init__(self) -> None:
        self.widths: list[int] = []
        self.threads: set[str] = set()
        self.scenario = "fake"

    def evaluate(self, plans, effects=None):
        plans = list(plans)
        self.threads.add(threading.current_thread().name)
        if any(p < 0 for p in plans):
            raise PlanError("negative plan")
        effs = effects if isinstance(effects, list) else [effects] * len(plans)
        offsets = [(e or {}).get("offset", 0.0) for e in effs]
        self.widths.append(len(plans))
        return [np.sin(p) + o for p, o in zip(plans, offsets)]


def search_job(seed: int, generations: int, popsize: int, effects=None):
    """A toy ask/tell search with its own seeded Generator: its trajectory depends on the outcomes it gets."""

    def job(ex):
        rng = np.random.default_rng(seed)
        mean, history = 0.5, []
        for _ in range(generations):
            xs = mean + rng.standard_normal(popsize)
            ys = ex.evaluate(list(np.abs(xs)), effects)
            mean = float(np.abs(xs[int(np.argmax(ys))]))
            history.append((list(xs), list(ys)))
        return history

    return job


def test_rounds_merge_the_jobs_batches_and_keep_each_jobs_results():
    jobs = [search_job(0, 5, 4), search_job(1, 3, 6), search_job(2, 5, 3, effects={"offset": 0.5})]
    alone = [job(FakeExecutor()) for job in jobs]
    shared = FakeExecutor()
    together = run_concurrently(shared, jobs)
    assert together == alone
    # 3 rounds with every job (4 + 6 + 3 = 13 rollouts), then 2 with the two longer ones (4 + 3)
    assert shared.widths == [13, 13, 13, 7, 7]
    assert shared.threads == {threading.current_thread().name}  # the executor runs in the calling thread only


def test_an_error_reaches_only_its_job():
    done = []

    def bad(ex):
        ex.evaluate([1.0])
        with pytest.raises(PlanError, match="negative"):
            ex.evaluate([0.5, -1.0])
        return "refused"

    def good(ex):
        out = [ex.evaluate([0.1 * k, 0.2]) for k in range(4)]
        done.append(out)
        return out

    ex = FakeExecutor()
    assert run_concurrently(ex, [good, bad, good])[1] == "refused"
    assert len(done) == 2 and done[0] == done[1] == [[np.sin(0.1 * k), np.sin(0.2)] for k in range(4)]


def test_a_job_that_raises_stops_the_others_at_their_next_batch():
    calls = []

    def failing(ex):
        ex.evaluate([1.0])
        raise ValueError("job failed")

    def long(ex):
        for k in range(50):
            ex.evaluate([0.1])
            calls.append(k)

    with pytest.raises(ValueError, match="job failed"):
        run_concurrently(FakeExecutor(), [long, failing, long])
    assert len(calls) <= 4  # stopped after a round or two, not after 50


def test_one_job_runs_directly_and_no_job_is_nothing():
    ex = FakeExecutor()
    assert run_concurrently(ex, []) == []
    assert run_concurrently(ex, [lambda e: e is ex]) == [True]


def test_stats_widths_and_pool_fill():
    stats = ExecutorStats(workers=2, widths=[10, 10, 20])
    assert stats.fill(16) == pytest.approx(40 / (16 + 16 + 32))
    assert stats.fill(64) == pytest.approx(40 / 192)
    d = stats.to_dict()
    assert d["batches"] == 3 and d["width_mean"] == pytest.approx(13.33) and d["width_max"] == 20
    other = ExecutorStats(rollouts=5, wall_s=1.0, busy_s=1.5, workers=4, widths=[5])
    stats.add(other)
    assert stats.widths == [10, 10, 20, 5] and stats.workers == 4 and stats.rollouts == 5


@pytest.fixture(scope="module")
def problem():
    from besdrake.search.refinement import RefinementProblem
    from besdrake.tasks.throwing.template_base import fitted_default_throw
    from besdrake.sim.scenario import load_scenario

    base = fitted_default_throw()
    base.execution_time = 2.3
    return RefinementProblem(load_scenario("nominal").robot, base)


def _refine_job(problem, k, out, episodes):
    from besdrake.search.refinement import refine

    return lambda ex: refine(problem, ex, episodes, seed=k, out_dir=out / f"run{k}", popsize=6, stop_on_success=False)


class Interrupting:
    """An executor that is interrupted (Ctrl-C) at its ``calls``-th batch."""

    def __init__(self, executor, calls: int) -> None:
        self.executor, self.calls = executor, calls

    def evaluate(self, plans, effects=None):
        self.calls -= 1
        if self.calls == 0:
            raise KeyboardInterrupt
        return self.executor.evaluate(plans, effects)


def test_concurrent_refinement_runs_equal_serial_ones_and_resume(problem, tmp_path):
    """Two CMA-ES runs on one serial executor: concurrently (interrupted in their third round, then resumed) they
    write the episodes of two runs made one after the other, bit for bit, in batches twice as wide. (Population 6:
    below 6, cma's mirrored sampling makes a resumed run differ from an uninterrupted one, with or without the
    scheduler.)"""
    from besdrake.sim import make_executor

    with make_executor("serial") as ex:
        alone = [_refine_job(problem, k, tmp_path / "alone", 18)(ex) for k in range(2)]
        alone_widths = list(ex.stats.widths)
    with make_executor("serial") as ex:
        with pytest.raises(KeyboardInterrupt):
            run_concurrently(Interrupting(ex, 3), [_refine_job(problem, k, tmp_path / "shared", 18) for k in range(2)])
        assert [(tmp_path / "shared" / f"run{k}" / "episodes.csv").read_text().count("\n") for k in range(2)] == [13, 13]
        resumed = run_concurrently(ex, [_refine_job(problem, k, tmp_path / "shared", 18) for k in range(2)])
        shared_widths = list(ex.stats.widths)
    for k in range(2):
        a = (tmp_path / "alone" / f"run{k}" / "episodes.csv").read_text()
        assert a == (tmp_path / "shared" / f"run{k}" / "episodes.csv").read_text()
        assert a.count("\n") == 19
        assert resumed[k].resumed and resumed[k].best_reward == alone[k].best_reward
    assert max(shared_widths) == 2 * max(alone_widths) == 12
    assert sum(shared_widths) == sum(alone_widths)


def test_rank_starts_simulates_every_imitated_movement_in_one_batch():
    from besdrake.search.refinement import RefinementProblem, rank_starts
    from besdrake.tasks.throwing.template_base import fitted_default_throw
    from tests.test_refinement import COMPI, StandIn

    bases = [fitted_default_throw() for _ in range(3)]
    for b, dx in zip(bases, (0.5, 0.0, 0.8)):
        b.goal = b.goal.copy()
        b.goal[1] += dx
    problems = [RefinementProblem(COMPI, b, retime=False) for b in bases]

    class Counting(StandIn):
        widths: list[int] = []

        def evaluate(self, plans):
            self.widths.append(len(plans))
            return super().evaluate(plans)

    ex = Counting()
    ranked = rank_starts(problems, ex)
    one_by_one = sorted(((i, p.evaluate(np.zeros((1, p.n_params)), StandIn())[0]) for i, p in enumerate(problems)), key=lambda ir: -ir[1].reward)
    assert ex.widths == [3]
    assert [i for i, _ in ranked] == [i for i, _ in one_by_one] and [r.reward for _, r in ranked] == [r.reward for _, r in one_by_one]


def test_learn_prints_and_reports_the_workers_figures():
    from besdrake.pipeline.learn import busy_line as _busy_line
    from besdrake.tasks.throwing.learn.report import _workers_table

    stats = ExecutorStats(rollouts=40, wall_s=10.0, busy_s=16.0, workers=2, widths=[20, 20]).to_dict() | {"stage_busy_share": 0.5}
    line = _busy_line(stats)
    assert "80% while simulating, 50% of the stage" in line and "width 20.0 mean, 20 max" in line and "16-worker pool 62% busy" in line
    table = _workers_table({"refine": {"summary": {"executor": stats}}, "pool": {"summary": {}}, "label": None})
    assert table[0] == "## Rollouts and workers" and len([ln for ln in table if ln.startswith("| refine |")]) == 1
    assert not any(ln.startswith("| pool") for ln in table)
