"""The search-loop driver: recording, failed episodes, executors, kill and resume."""

from __future__ import annotations

import concurrent.futures as cf
import os
import shutil

import numpy as np
import pytest

from besdrake.search.cmaes import CMAES
from besdrake.search.creps import CREPS
from besdrake.search.loop import EPISODES_FILE, ResumeError, batch_evaluator, run_contextual_search, run_search
from besdrake.search.reps import REPS
from besdrake.search.testfunctions import ContextualQuadratic, reward_of, sphere

BOUNDS = np.array([[1.0, 2.5], [-1.0, 1.0]])


def make_cmaes(seed: int = 0) -> CMAES:
    return CMAES(np.full(4, 1.5), 0.5, np.random.default_rng(seed))


class Counting:
    """Episode evaluator that counts calls per parameter vector and can be told to 'die' at call k."""

    def __init__(self, kill_at: int | None = None) -> None:
        self.calls: list[tuple[float, ...]] = []
        self.kill_at = kill_at

    def episode(self, params: np.ndarray) -> float:
        if self.kill_at is not None and len(self.calls) == self.kill_at:
            raise KeyboardInterrupt  # the user presses Ctrl-C / the job is killed
        self.calls.append(tuple(params))
        return float(-sphere(params))

    def batch(self, candidates: np.ndarray) -> np.ndarray:
        if self.kill_at is not None and len(self.calls) >= self.kill_at:
            raise KeyboardInterrupt
        self.calls.extend(tuple(p) for p in candidates)
        return -sphere(candidates)


def test_run_search_records_every_episode_and_state(tmp_path):
    result = run_search(make_cmaes(), reward_of(sphere), 200, out_dir=tmp_path)
    assert result.n_evaluations == 200  # popsize 8 divides 200
    assert result.best_reward > -1e-2 and result.stop_reason == "budget" and not result.resumed
    lines = (tmp_path / EPISODES_FILE).read_text().splitlines()
    assert len(lines) == 201 and lines[0].startswith("generation,index,reward,failed,error,p0")
    assert (tmp_path / "optimizer.json").exists() and (tmp_path / "optimizer.npz").exists()
    np.testing.assert_array_equal(result.generations, np.repeat(np.arange(25), 8))
    np.testing.assert_allclose(result.rewards, -sphere(result.params))
    assert result.best_reward == result.rewards.max()


@pytest.mark.parametrize("mode", ["batch", "episode"])
def test_killed_run_resumes_without_repeating_or_losing_episodes(tmp_path, mode):
    reference = Counting()
    kwargs = {"evaluate_batch": reference.batch} if mode == "batch" else {"evaluate_episode": reference.episode}
    expected = run_search(make_cmaes(), n_evaluations=160, **kwargs)

    killed = Counting(kill_at=61)  # episode mode: in the middle of generation 7 (popsize 8)
    kwargs = {"evaluate_batch": killed.batch} if mode == "batch" else {"evaluate_episode": killed.episode}
    with pytest.raises(KeyboardInterrupt):
        run_search(make_cmaes(), n_evaluations=160, out_dir=tmp_path, **kwargs)
    recorded = len((tmp_path / EPISODES_FILE).read_text().splitlines()) - 1
    assert recorded == len(killed.calls)  # everything evaluated before the kill is on disk

    resumed_eval = Counting()
    kwargs = {"evaluate_batch": resumed_eval.batch} if mode == "batch" else {"evaluate_episode": resumed_eval.episode}
    result = run_search(make_cmaes(), n_evaluations=160, out_dir=tmp_path, **kwargs)
    assert result.resumed
    assert len(killed.calls) + len(resumed_eval.calls) == 160  # nothing evaluated twice
    assert not set(killed.calls) & set(resumed_eval.calls)
    np.testing.assert_array_equal(result.params, expected.params)  # same search as without the kill
    np.testing.assert_array_equal(result.rewards, expected.rewards)
    assert result.best_reward == expected.best_reward


def test_episodes_logged_after_the_last_saved_state_are_reused(tmp_path):
    """Killed after recording a generation but before its state was saved (state is one generation behind)."""
    run_search(make_cmaes(), reward_of(sphere), 40, out_dir=tmp_path)
    snapshot = tmp_path / "snap"
    snapshot.mkdir()
    for name in ("optimizer.json", "optimizer.npz"):
        shutil.copy(tmp_path / name, snapshot / name)
    run_search(make_cmaes(), reward_of(sphere), 48, out_dir=tmp_path)
    for name in ("optimizer.json", "optimizer.npz"):
        shutil.copy(snapshot / name, tmp_path / name)  # the state as it was before generation 5
    counter = Counting()
    result = run_search(make_cmaes(), evaluate_batch=counter.batch, n_evaluations=64, out_dir=tmp_path)
    assert len(counter.calls) == 16 and result.n_evaluations == 64
    expected = run_search(make_cmaes(), reward_of(sphere), 64)
    np.testing.assert_array_equal(result.params, expected.params)


def test_a_truncated_last_row_is_dropped_and_re_evaluated(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        run_search(make_cmaes(), evaluate_episode=Counting(kill_at=12).episode, n_evaluations=40, out_dir=tmp_path)
    path = tmp_path / EPISODES_FILE
    text = path.read_text()
    path.write_text(text[:-7])  # killed while writing the 12th row
    counter = Counting()
    result = run_search(make_cmaes(), evaluate_episode=counter.episode, n_evaluations=40, out_dir=tmp_path)
    assert len(counter.calls) == 40 - 11
    np.testing.assert_array_equal(result.params, run_search(make_cmaes(), reward_of(sphere), 40).params)


def test_failed_episodes_are_recorded_with_a_penalty_and_the_search_goes_on(tmp_path):
    def episode(params):
        k = int(abs(params[0]) * 1e6) % 10
        if k == 0:
            raise RuntimeError("simulation diverged")
        if k == 1:
            return float("nan")
        if k == 2:
            return "not a reward"
        return float(-sphere(params))

    result = run_search(make_cmaes(), evaluate_episode=episode, n_evaluations=400, out_dir=tmp_path)
    assert result.n_evaluations == 400
    assert 0.15 * 400 < result.n_failed < 0.45 * 400
    assert np.isnan(result.rewards[result.failed]).all() and np.isfinite(result.rewards[~result.failed]).all()
    errors = {e.split(":")[0] for e, f in zip(result.errors, result.failed) if f}
    assert errors == {"RuntimeError", "non-finite reward nan", "reward is not a number"}
    assert result.best_reward > -1e-3  # the search still converged
    text = (tmp_path / EPISODES_FILE).read_text()
    assert "simulation diverged" in text


def test_a_failing_batch_fails_all_its_episodes_but_not_the_search():
    calls = {"n": 0}

    def batch(candidates):
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError("worker lost")
        return -sphere(candidates)

    result = run_search(make_cmaes(), batch, 80)
    assert result.n_failed == 8 and result.failed[16:24].all()
    assert result.errors[16] == "OSError: worker lost"
    with pytest.raises(ValueError, match="returned 3 rewards for 8"):
        run_search(make_cmaes(), lambda c: [0.0, 0.0, 0.0], 8)


def _episode_that_kills_its_worker(params: np.ndarray) -> float:
    if params[0] > 1.9:  # a few candidates: the worker process dies
        os._exit(1)
    return float(-sphere(params))


def test_thread_pool_executor_gives_the_same_search_as_serial():
    with cf.ThreadPoolExecutor(2) as pool:
        threaded = run_search(make_cmaes(), evaluate_episode=lambda p: float(-sphere(p)), executor=pool, n_evaluations=80)
    serial = run_search(make_cmaes(), reward_of(sphere), 80)
    # threads finish in any order, so rows are recorded in completion order; the search is the same
    assert threaded.n_evaluations == serial.n_evaluations == 80
    for g in range(10):
        a = threaded.params[threaded.generations == g]
        b = serial.params[serial.generations == g]
        np.testing.assert_array_equal(a[np.lexsort(a.T)], b[np.lexsort(b.T)])
    assert threaded.best_reward == serial.best_reward


def test_dead_worker_process_is_a_failed_episode_and_the_pool_is_rebuilt():
    result = run_search(
        CMAES(np.full(3, 1.5), 0.3, np.random.default_rng(1)),
        evaluate_episode=_episode_that_kills_its_worker,
        executor=lambda: cf.ProcessPoolExecutor(2),
        n_evaluations=70,
    )
    assert result.n_evaluations == 70
    assert result.n_failed > 0
    assert any("BrokenProcessPool" in e for e in result.errors)
    # the generations after a crash still got evaluated by a fresh pool
    last = result.generations.max()
    assert (~result.failed[result.generations == last]).any()


def test_resume_refuses_a_folder_of_another_run(tmp_path):
    run_search(make_cmaes(seed=0), reward_of(sphere), 40, out_dir=tmp_path)
    with pytest.raises(ResumeError, match="CMAES"):
        run_search(REPS(np.zeros(4), 1.0, np.random.default_rng(0)), reward_of(sphere), 80, out_dir=tmp_path)
    # a log whose pending episodes do not match the optimizer's candidates
    other = tmp_path / "other"
    with pytest.raises(KeyboardInterrupt):
        run_search(make_cmaes(seed=0), evaluate_episode=Counting(kill_at=5).episode, n_evaluations=40, out_dir=other)
    with pytest.raises(ResumeError, match="another run"):
        run_search(make_cmaes(seed=1), reward_of(sphere), 40, out_dir=other)
    corrupt = tmp_path / "corrupt"
    run_search(make_cmaes(), reward_of(sphere), 16, out_dir=corrupt)
    path = corrupt / EPISODES_FILE
    lines = path.read_text().splitlines()
    lines[3] = lines[3].replace(",", ",x", 1)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ResumeError, match="line 4"):
        run_search(make_cmaes(), reward_of(sphere), 32, out_dir=corrupt)


def test_callback_can_stop_and_optimizer_stop_is_honoured():
    seen = []
    result = run_search(make_cmaes(), reward_of(sphere), 10**6, callback=lambda info: seen.append(info.generation) or info.generation == 3)
    assert seen == [1, 2, 3] and result.stop_reason == "callback" and result.n_evaluations == 24
    stopping = CMAES(np.ones(2), 0.5, np.random.default_rng(0), tolfun=1e-3, tolx=1e-3)
    result = run_search(stopping, reward_of(sphere), 10**6)
    assert result.stop_reason == "optimizer" and result.n_evaluations < 10**6


def test_contextual_search_kill_and_resume_matches_uninterrupted_run(tmp_path):
    problem = ContextualQuadratic.random(3, 2, np.random.default_rng(3))

    def make():
        return CREPS(np.zeros(3), 2, 1.0, np.random.default_rng(0), n_samples_per_update=20, active=True, context_bounds=BOUNDS)

    class Flaky:
        """Every 13th episode fails; the process is killed before episode ``kill_at``."""

        def __init__(self, start=0, kill_at=None):
            self.n, self.kill_at = start, kill_at

        def __call__(self, context, params):
            if self.n == self.kill_at:
                raise KeyboardInterrupt
            self.n += 1
            if self.n % 13 == 0:
                raise RuntimeError("ball never released")
            return problem.reward(context, params)

    expected = run_contextual_search(make(), Flaky(), 120, BOUNDS)
    killed = Flaky(kill_at=57)
    with pytest.raises(KeyboardInterrupt):
        run_contextual_search(make(), killed, 120, BOUNDS, out_dir=tmp_path)
    resumed = Flaky(start=killed.n)
    result = run_contextual_search(make(), resumed, 120, BOUNDS, out_dir=tmp_path)
    assert result.resumed and killed.n == 57 and resumed.n == 120  # no episode evaluated twice
    np.testing.assert_array_equal(result.contexts, expected.contexts)
    np.testing.assert_array_equal(result.params, expected.params)
    assert result.n_failed == expected.n_failed == 120 // 13
    assert all(e == "RuntimeError: ball never released" for e, f in zip(result.errors, result.failed) if f)
    np.testing.assert_array_equal(result.optimizer.W, expected.optimizer.W)


def test_contextual_search_rejects_bad_bounds():
    opt = CREPS(np.zeros(3), 2, 1.0, np.random.default_rng(0))
    with pytest.raises(ValueError, match="context_bounds"):
        run_contextual_search(opt, lambda s, p: 0.0, 10, np.array([[1.0, 0.0], [0.0, 1.0]]))


class FakeRolloutExecutor:
    """Stands in for a besdrake.sim executor: evaluate(plans) -> outcomes, rejecting the whole batch
    when one plan is invalid (as the real one validates plans before simulating)."""

    def __init__(self):
        self.batches = []

    def evaluate(self, plans):
        self.batches.append(len(plans))
        for plan in plans:
            if plan["speed"] > 2.0:
                raise ValueError(f"plan exceeds the joint speed limit ({plan['speed']:.2f})")
        return [{"distance": float(np.linalg.norm(plan["params"])), "dropped": plan["params"][1] > 1.8} for plan in plans]


def test_batch_evaluator_keeps_failures_with_their_episode():
    executor = FakeRolloutExecutor()

    def to_input(params):
        if params[2] > 1.9:
            raise ValueError("execution time must be positive")
        return {"params": params, "speed": abs(params[0])}

    def to_reward(outcome):
        if outcome["dropped"]:
            raise RuntimeError("ball dropped early")
        return -outcome["distance"] ** 2

    evaluate = batch_evaluator(executor.evaluate, to_input, to_reward)
    candidates = np.array([[0.1, 0.0, 0.0], [2.5, 0.0, 0.0], [0.2, 1.9, 0.0], [0.3, 0.0, 2.0], [0.4, 0.0, 0.0]])
    rewards = evaluate(candidates)
    assert rewards[0] == pytest.approx(-0.01) and rewards[4] == pytest.approx(-0.16)
    assert "joint speed limit" in str(rewards[1]) and "dropped" in str(rewards[2]) and "execution time" in str(rewards[3])
    assert executor.batches[0] == 4  # one batch call, then one call per plan to isolate the invalid one

    result = run_search(CMAES(np.full(3, 1.5), 0.5, np.random.default_rng(0)), evaluate, 160)
    assert 0 < result.n_failed < 160 and result.best_reward > -0.5
    assert any("ValueError: plan exceeds the joint speed limit" in e for e in result.errors)
    assert any("RuntimeError: ball dropped early" in e for e in result.errors)


@pytest.mark.slow
def test_cmaes_aims_the_default_throw_through_the_rollout_executor(tmp_path):
    """Integration with besdrake.sim: search amplitude and yaw of the default throw for a target."""
    from besdrake.sim import executors
    from besdrake.tasks.throwing import throws
    target = np.array([1.8, 0.3])

    def to_reward(outcome):
        if not outcome.ok:
            raise RuntimeError(f"flagged throw: {[k for k, v in outcome.flags.items() if v]}")
        return -float(np.sum((np.asarray(outcome.touchdown)[:2] - target) ** 2))

    with executors.make_executor("serial") as executor:
        evaluate = batch_evaluator(executor.evaluate, lambda p: throws.default_throw(amplitude=p[0], yaw=p[1]), to_reward)
        opt = CMAES(np.array([0.35, 0.0]), 0.1, np.random.default_rng(0), bounds=np.array([[0.1, 0.7], [-0.8, 0.8]]))
        result = run_search(opt, evaluate, 60, out_dir=tmp_path)
    assert np.sqrt(-result.best_reward) < 0.10  # metres from the target; measured 0.033


@pytest.mark.parametrize("mode", ["batch", "episode"])
def test_contextual_search_in_batches_resumes_exactly(tmp_path, mode):
    problem = ContextualQuadratic.random(3, 2, np.random.default_rng(7))

    def make():
        return CREPS(np.zeros(3), 2, 1.0, np.random.default_rng(2), n_samples_per_update=20)

    class Evaluations:
        def __init__(self, kill_at=None):
            self.n, self.kill_at = 0, kill_at

        def batch(self, contexts, params):
            if self.kill_at is not None and self.n >= self.kill_at:
                raise KeyboardInterrupt
            self.n += len(params)
            return [problem.reward(s, p) if p[0] < 2.5 else ValueError("too far") for s, p in zip(contexts, params)]

        def episode(self, context, params):
            if self.n == self.kill_at:
                raise KeyboardInterrupt
            self.n += 1
            return problem.reward(context, params)

    def kwargs(ev):
        return {"evaluate": None, "evaluate_batch": ev.batch} if mode == "batch" else {"evaluate": ev.episode}

    expected = run_contextual_search(make(), n_episodes=200, context_bounds=BOUNDS, batch_size=20, **kwargs(Evaluations()))
    killed = Evaluations(kill_at=70)
    with pytest.raises(KeyboardInterrupt):
        run_contextual_search(make(), n_episodes=200, context_bounds=BOUNDS, out_dir=tmp_path, batch_size=20, **kwargs(killed))
    resumed = Evaluations()
    result = run_contextual_search(make(), n_episodes=200, context_bounds=BOUNDS, out_dir=tmp_path, batch_size=20, **kwargs(resumed))
    assert killed.n + resumed.n == 200  # batch mode: 60 + 140; episode mode: 70 + 130
    np.testing.assert_array_equal(result.params, expected.params)
    np.testing.assert_array_equal(result.optimizer.W, expected.optimizer.W)
    assert result.n_failed == expected.n_failed
    np.testing.assert_array_equal(np.unique(result.generations), np.arange(10))
    regret = problem.regret(BOUNDS.mean(axis=1), result.optimizer.policy(BOUNDS.mean(axis=1)))
    assert regret < problem.regret(BOUNDS.mean(axis=1), np.zeros(3))  # it learned something in 200 episodes
