"""Independent jobs that share one executor: their rollout batches run together, as one wider batch.

A CMA-ES generation has about ten candidates, so a pool of 16 or 64 workers idles while one search waits for
its batch. :func:`run_concurrently` runs several independent jobs (refinement runs with their own seeds, ...)
at the same time, each in its own thread, each calling ``evaluate`` on a handle of the shared executor. A
round starts when every unfinished job waits for its batch: the batches of all of them, in job order, go to
the executor in one ``evaluate`` call, and every job gets back exactly the outcomes of its own plans.

Results are those of running the jobs one after the other: a rollout's outcome depends only on its plan and
effects (every rollout starts from the same reset Context, see :mod:`besdrake.sim.executors`), each job keeps
its own seeded Generator, and its steps between batches (ask, tell, writing its trials to disk before they are
used) run in its own thread, in its own order. The jobs' threads never simulate: the executor is called from the
calling thread only (a serial executor's Drake Diagram stays on it). A batch that the executor refuses
(a :class:`~besdrake.plan.PlanError` of one job) is split again so that only that job sees the error.
"""

from __future__ import annotations

import threading
from typing import Any, Callable, Sequence, TypeVar

T = TypeVar("T")


class _Stopped(BaseException):
    """The scheduler stopped (the calling thread was interrupted) while a job waited for its batch. Not an
    ``Exception``: a search loop must not record it as a failed episode (it stops the job, as an interrupt does)."""


class _Handle:
    """What a job sees of the shared executor: ``evaluate`` waits for the round; other attributes are the executor's."""

    def __init__(self, rounds: "_Rounds", index: int) -> None:
        self._rounds = rounds
        self._index = index

    def evaluate(self, plans: Sequence[Any], effects: dict | list | None = None) -> list[Any]:
        return self._rounds.submit(self._index, list(plans), effects)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._rounds.executor, name)


class _Rounds:
    """The requests of the waiting jobs and their replies; the calling thread serves rounds until every job ends."""

    def __init__(self, executor, n_jobs: int) -> None:
        self.executor = executor
        self.cond = threading.Condition()
        self.pending: dict[int, tuple[list, Any]] = {}
        self.replies: dict[int, tuple[bool, Any]] = {}
        self.running = n_jobs  # jobs neither finished nor waiting for a batch
        self.stopped = False

    def submit(self, index: int, plans: list, effects) -> list[Any]:
        with self.cond:
            if self.stopped:
                raise _Stopped()
            self.pending[index] = (plans, effects)
            self.running -= 1
            self.cond.notify_all()
            while index not in self.replies and not self.stopped:
                self.cond.wait()
            if index not in self.replies:
                raise _Stopped()
            ok, value = self.replies.pop(index)
        if ok:
            return value
        raise value

    def finished(self) -> None:
        with self.cond:
            self.running -= 1
            self.cond.notify_all()

    def serve(self) -> None:
        """Evaluate rounds until every job has finished."""
        while True:
            with self.cond:
                while self.running > 0:
                    self.cond.wait()
                if not self.pending or self.stopped:
                    return
                batch = sorted(self.pending.items())
                self.pending.clear()
            replies = _evaluate_round(self.executor, batch)
            with self.cond:
                self.replies.update(replies)
                self.running += len(replies)
                self.cond.notify_all()

    def stop(self) -> None:
        with self.cond:
            self.stopped = True
            self.cond.notify_all()


def _merged_effects(requests: list[tuple[list, Any]]) -> list | None:
    """One effects entry per plan of the merged batch (None when no request has effects)."""
    if all(e is None for _, e in requests):
        return None
    out: list = []
    for plans, effects in requests:
        if effects is None or isinstance(effects, dict):
            out += [effects] * len(plans)
        else:
            effects = list(effects)
            if len(effects) != len(plans):
                raise ValueError("effects do not match the plans")
            out += effects
    return out


def _call(executor, plans: list, effects) -> list[Any]:
    """``executor.evaluate``, without ``effects`` where there are none (an evaluator may take plans only)."""
    return executor.evaluate(plans) if effects is None else executor.evaluate(plans, effects)


def _evaluate_round(executor, batch: list[tuple[int, tuple[list, Any]]]) -> dict[int, tuple[bool, Any]]:
    """Every request of the round in one ``evaluate`` call; where the executor refuses the merged batch, each
    request alone (so that an error reaches only the job whose plans caused it)."""
    requests = [req for _, req in batch]
    try:
        outcomes = _call(executor, [p for plans, _ in requests for p in plans], _merged_effects(requests))
        if len(outcomes) != sum(len(plans) for plans, _ in requests):
            raise RuntimeError(f"executor returned {len(outcomes)} outcomes for {sum(len(plans) for plans, _ in requests)} plans")
    except Exception:  # noqa: BLE001 - split the round: each job gets its own result or error
        replies = {}
        for index, (plans, effects) in batch:
            try:
                replies[index] = (True, _call(executor, plans, effects))
            except Exception as err:  # noqa: BLE001 - handed to the job that asked
                replies[index] = (False, err)
        return replies
    replies, start = {}, 0
    for index, (plans, _) in batch:
        replies[index] = (True, outcomes[start : start + len(plans)])
        start += len(plans)
    return replies


def run_concurrently(executor, jobs: Sequence[Callable[[Any], T]]) -> list[T]:
    """Run every ``job(executor_handle)`` at the same time, their rollout batches merged round by round into one
    call of ``executor.evaluate``; their results in job order. A job that raises stops the others at their next batch
    (what they wrote stays on disk, as after an interrupt) and its exception is raised here (the first in job order).
    One job runs in this thread, directly on ``executor``."""
    jobs = list(jobs)
    if len(jobs) <= 1:
        return [job(executor) for job in jobs]
    rounds = _Rounds(executor, len(jobs))
    results: list[Any] = [None] * len(jobs)
    errors: list[BaseException | None] = [None] * len(jobs)

    def work(i: int) -> None:
        try:
            results[i] = jobs[i](_Handle(rounds, i))
        except BaseException as err:  # noqa: BLE001 - re-raised in the calling thread
            errors[i] = err
            rounds.stop()  # fail fast, as one job after the other would
        finally:
            rounds.finished()

    threads = [threading.Thread(target=work, args=(i,), name=f"besdrake-job-{i}", daemon=True) for i in range(len(jobs))]
    for t in threads:
        t.start()
    try:
        rounds.serve()
    except BaseException:
        rounds.stop()  # e.g. KeyboardInterrupt: the waiting jobs end; what they wrote stays on disk
        for t in threads:
            t.join()
        raise
    for t in threads:
        t.join()
    first = next((e for e in errors if e is not None and not isinstance(e, _Stopped)), None)
    if first is not None:
        raise first
    return results
