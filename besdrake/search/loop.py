"""The search-loop driver: ask -> evaluate -> record -> tell, resumable, tolerant to failed episodes.

:func:`run_search` drives an :class:`~besdrake.search.base.Optimizer`,
:func:`run_contextual_search` a :class:`~besdrake.search.base.ContextualOptimizer`.

With an ``out_dir`` both keep two things on disk:

* ``episodes.csv``: one row per evaluated episode (generation, index in the batch, reward, failed
  flag, error message, context for contextual searches, parameters), appended, flushed and fsynced
  as soon as the episode is evaluated, *before* the optimizer is told;
* ``optimizer.json`` + ``optimizer.npz``: the optimizer's :meth:`state_dict` and the loop counters,
  written atomically after every generation (every batch of ``batch_size`` episodes for
  contextual searches).

Calling the driver again with the same ``out_dir`` (and an optimizer of the same type) resumes: the
optimizer is restored from the saved state, and because a restored optimizer asks exactly the
candidates it asked before the interruption, episodes that were evaluated but not yet told are
taken from ``episodes.csv`` instead of being evaluated again. Nothing is repeated or lost; a log
that does not match the optimizer's candidates (another run's folder) is an error.

Failed episodes: a NaN or infinite reward, a reward that is not a number, or an evaluation that
raises an ``Exception`` (a rollout that fails, a worker process that dies) is recorded with
``failed=1`` and its error message, and the optimizer is told a NaN reward for it: by the
convention of :mod:`besdrake.search.base` every optimizer treats NaN as a failed episode (the local
optimizers replace it by the worst finite reward seen minus
:data:`~besdrake.search.base.FAILED_EPISODE_PENALTY`; a model-based one may leave it out of its
model). ``KeyboardInterrupt`` is not caught: it stops the run, and what was recorded stays on disk
for the resume.
"""

from __future__ import annotations

import concurrent.futures as cf
import csv
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from besdrake.search.base import (
    ContextualOptimizer,
    Optimizer,
    SearchResult,
    load_state,
    save_state,
)

EPISODES_FILE = "episodes.csv"
STATE_FILE = "optimizer"  # .json + .npz
_MATCH_RTOL = 1e-12


class ResumeError(ValueError):
    """The run folder does not belong to this search (other optimizer, other seed, other problem)."""


@dataclass
class LoopResult(SearchResult):
    """:class:`SearchResult` plus the full episode record of the run (resumed parts included).

    ``rewards`` are the raw rewards (NaN for failed episodes); ``failed`` flags them.
    """

    params: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    contexts: np.ndarray | None = None
    failed: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    generations: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    errors: list[str] = field(default_factory=list)
    n_failed: int = 0
    resumed: bool = False
    stop_reason: str = "budget"  # "budget" | "optimizer" | "callback"
    optimizer: Any = field(default=None, repr=False)


@dataclass
class GenerationInfo:
    """What a callback sees after each generation (after each episode for contextual searches)."""

    generation: int
    candidates: np.ndarray
    rewards: np.ndarray  # raw, NaN where failed
    failed: np.ndarray
    n_evaluations: int
    optimizer: Any
    contexts: np.ndarray | None = None


# ---------------------------------------------------------------------------------------------
# episode log
# ---------------------------------------------------------------------------------------------
@dataclass
class _Row:
    generation: int
    index: int
    reward: float
    failed: bool
    error: str
    context: np.ndarray
    params: np.ndarray


class _EpisodeLog:
    """Append-only CSV of episodes, flushed and fsynced row by row."""

    def __init__(self, path: Path | None, n_params: int, n_context: int) -> None:
        self.path = path
        self.n_params = n_params
        self.n_context = n_context
        self.rows: list[_Row] = []
        self._logged: dict[int, dict[int, _Row]] = {}  # rows read from disk, by generation and index
        self.header = (
            ["generation", "index", "reward", "failed", "error"]
            + [f"c{i}" for i in range(n_context)]
            + [f"p{i}" for i in range(n_params)]
        )
        if path is not None and path.exists():
            self._read()

    def _read(self) -> None:
        assert self.path is not None
        text = self.path.read_text()
        if text and not text.endswith("\n"):
            # killed while writing the last row: drop the partial row
            text = text[: text.rfind("\n") + 1]
            self.path.write_text(text)
        reader = csv.reader(text.splitlines())
        header = next(reader, None)
        if header is None:
            return
        if header != self.header:
            raise ResumeError(
                f"{self.path}: columns {header[:7]}... do not match this search "
                f"({self.n_params} parameters, {self.n_context} context dimensions)"
            )
        for line_no, fields in enumerate(reader, start=2):
            try:
                values = [float(v) for v in fields[5:]]
                row = _Row(
                    int(fields[0]),
                    int(fields[1]),
                    float(fields[2]),
                    fields[3] == "1",
                    fields[4],
                    np.array(values[: self.n_context]),
                    np.array(values[self.n_context :]),
                )
            except (ValueError, IndexError) as err:
                raise ResumeError(f"{self.path}, line {line_no}: corrupt episode row ({err})") from err
            if row.params.size != self.n_params:
                raise ResumeError(f"{self.path}, line {line_no}: expected {self.n_params} parameters")
            self.rows.append(row)
            self._logged.setdefault(row.generation, {})[row.index] = row

    def append(self, *rows: _Row) -> None:
        """Append rows and make them durable (one flush + fsync for all of them)."""
        self.rows.extend(rows)
        if self.path is None or not rows:
            return
        new = not self.path.exists() or self.path.stat().st_size == 0
        with open(self.path, "a", newline="") as handle:
            writer = csv.writer(handle)
            if new:
                writer.writerow(self.header)
            for row in rows:
                writer.writerow(
                    [row.generation, row.index, repr(float(row.reward)), int(row.failed), row.error]
                    + [repr(float(v)) for v in row.context]
                    + [repr(float(v)) for v in row.params]
                )
            handle.flush()
            os.fsync(handle.fileno())

    def replay(
        self, generation: int, params: np.ndarray, contexts: np.ndarray | None, where: Path | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Raw rewards, failed and done masks for a batch of ``len(params)`` episodes of ``generation``,
        filled from its rows read from disk (evaluated before a restart, maybe never told).

        :class:`ResumeError` when a logged row is not an episode of this batch (another run's folder).
        """
        n = len(params)
        raw = np.full(n, np.nan)
        failed = np.zeros(n, dtype=bool)
        done = np.zeros(n, dtype=bool)
        for index, row in self._logged.pop(generation, {}).items():
            if index >= n:
                raise ResumeError(f"{where}: episode {generation}/{index} does not exist in the optimizer's batch of {n}")
            _check_match(row, params[index], None if contexts is None else contexts[index], where)
            raw[index], failed[index], done[index] = row.reward, row.failed, True
        return raw, failed, done

    def result(self, optimizer: Any, resumed: bool, stop_reason: str, contextual: bool) -> LoopResult:
        rewards = np.array([row.reward for row in self.rows], dtype=float)
        params = np.array([row.params for row in self.rows]).reshape(-1, self.n_params)
        failed = np.array([row.failed for row in self.rows], dtype=bool)
        ok = np.flatnonzero(~failed & np.isfinite(rewards))
        if ok.size:
            best = ok[np.argmax(rewards[ok])]
            best_params, best_reward = params[best].copy(), float(rewards[best])
        else:
            best_params, best_reward = np.full(self.n_params, np.nan), -np.inf
        return LoopResult(
            best_params=best_params,
            best_reward=best_reward,
            n_evaluations=len(self.rows),
            rewards=rewards,
            params=params,
            contexts=np.array([row.context for row in self.rows]).reshape(-1, self.n_context) if contextual else None,
            failed=failed,
            generations=np.array([row.generation for row in self.rows], dtype=int),
            errors=[row.error for row in self.rows],
            n_failed=int(failed.sum()),
            resumed=resumed,
            stop_reason=stop_reason,
            optimizer=optimizer,
        )


def _as_reward(value: Any) -> tuple[float, str]:
    """A float reward and an error message ('' when the reward is usable).

    An exception instance in place of a reward marks a failed episode with its message.
    """
    if isinstance(value, BaseException):
        return np.nan, _error_text(value)
    try:
        reward = float(value)
    except (TypeError, ValueError):
        return np.nan, f"reward is not a number: {value!r}"
    if not np.isfinite(reward):
        return np.nan, f"non-finite reward {reward!r}"
    return reward, ""


def _error_text(err: BaseException) -> str:
    return f"{type(err).__name__}: {err}".replace("\n", " ")[:500]


def _restore(optimizer: Any, out_dir: Path | None) -> tuple[Any, dict[str, Any] | None]:
    if out_dir is None or not (out_dir / f"{STATE_FILE}.json").exists():
        return optimizer, None
    recover = f"to recover, delete the folder {out_dir} (that search starts again) or use a new output folder"
    try:
        saved = load_state(out_dir / STATE_FILE)
        loop = saved.get("loop", {}) if isinstance(saved, dict) else None
        if not isinstance(loop, dict):
            raise ValueError("no 'loop' record")
    except (OSError, ValueError, KeyError, TypeError, EOFError) as err:  # json/np.load/zip errors on damaged files
        raise ResumeError(f"the saved search state {out_dir / STATE_FILE}.json/.npz is damaged ({type(err).__name__}: {err}); {recover}") from None
    if loop.get("optimizer_type") != type(optimizer).__name__:
        raise ResumeError(
            f"{out_dir} holds the state of a {loop.get('optimizer_type')!r} search, not of {type(optimizer).__name__!r}; "
            "use another out_dir or the same optimizer"
        )
    try:
        return type(optimizer).from_state(saved["optimizer"]), loop
    except (ValueError, KeyError, TypeError, IndexError) as err:
        raise ResumeError(f"the saved search state {out_dir / STATE_FILE}.json is damaged ({type(err).__name__}: {err}); {recover}") from None


def _save(optimizer: Any, out_dir: Path | None, loop: dict[str, Any]) -> None:
    if out_dir is not None:
        save_state({"optimizer": optimizer.state_dict(), "loop": {**loop, "optimizer_type": type(optimizer).__name__}}, out_dir / STATE_FILE)


def _check_match(row: _Row, params: np.ndarray, context: np.ndarray | None, where: Path | None) -> None:
    same = np.allclose(row.params, params, rtol=_MATCH_RTOL, atol=1e-300)
    if context is not None:
        same = same and np.allclose(row.context, context, rtol=_MATCH_RTOL, atol=1e-300)
    if not same:
        raise ResumeError(
            f"{where}: episode {row.generation}/{row.index} in the log differs from what the restored optimizer asks; "
            "the folder belongs to another run (different seed, optimizer settings or problem)"
        )


# ---------------------------------------------------------------------------------------------
# evaluation of one batch
# ---------------------------------------------------------------------------------------------
def batch_evaluator(
    evaluate_many: Callable[[list[Any]], Sequence[Any]],
    to_input: Callable[[np.ndarray], Any] = lambda params: params,
    to_reward: Callable[[Any], float] = float,
) -> Callable[[np.ndarray], list[Any]]:
    """An ``evaluate_batch`` for :func:`run_search` around a batch evaluator such as a rollout executor.

    ``evaluate_many(inputs) -> outputs`` evaluates a list in one call (e.g.
    ``besdrake.sim`` executors' ``evaluate(plans) -> outcomes``); ``to_input`` turns a parameter
    vector into an input (e.g. a motion plan) and ``to_reward`` an output into a reward. Failures
    stay with their episode: a parameter vector that ``to_input`` rejects, an output ``to_reward``
    rejects, or, when ``evaluate_many`` raises for the whole batch (one invalid plan fails the
    call), the inputs it rejects when evaluated one at a time, become failed episodes with their
    error message; the rest of the batch is evaluated normally.
    """

    def evaluate_batch(candidates: np.ndarray) -> list[Any]:
        results: list[Any] = [None] * len(candidates)
        inputs: list[tuple[int, Any]] = []
        for i, params in enumerate(candidates):
            try:
                inputs.append((i, to_input(params)))
            except Exception as err:
                results[i] = err
        try:
            outputs = list(evaluate_many([item for _, item in inputs])) if inputs else []
            if len(outputs) != len(inputs):
                raise ValueError(f"evaluate_many returned {len(outputs)} outputs for {len(inputs)} inputs")
        except Exception:
            outputs = []
            for _, item in inputs:  # isolate the failing input(s)
                try:
                    outputs.extend(evaluate_many([item]))
                except Exception as err:
                    outputs.append(err)
        for (i, _), output in zip(inputs, outputs):
            if isinstance(output, BaseException):
                results[i] = output
                continue
            try:
                results[i] = to_reward(output)
            except Exception as err:
                results[i] = err
        return results

    return evaluate_batch


ExecutorLike = cf.Executor | Callable[[], cf.Executor]


class _Evaluator:
    """Evaluates the missing episodes of a batch and records each as soon as it is known."""

    def __init__(
        self,
        evaluate_batch: Callable[[np.ndarray], Sequence[float]] | None,
        evaluate_episode: Callable[[np.ndarray], float] | None,
        executor: ExecutorLike | None,
    ) -> None:
        if (evaluate_batch is None) == (evaluate_episode is None):
            raise ValueError("give exactly one of evaluate_batch or evaluate_episode")
        if executor is not None and evaluate_episode is None:
            raise ValueError("an executor needs evaluate_episode (a function of one parameter vector)")
        self.evaluate_batch = evaluate_batch
        self.evaluate_episode = evaluate_episode
        self._factory = executor if executor is not None and not isinstance(executor, cf.Executor) else None
        self._executor = executor if isinstance(executor, cf.Executor) else None

    def close(self) -> None:
        if self._factory is not None and self._executor is not None:
            self._executor.shutdown(wait=True, cancel_futures=True)
            self._executor = None

    def _get_executor(self) -> cf.Executor | None:
        if self._executor is None and self._factory is not None:
            self._executor = self._factory()
        return self._executor

    def run(self, candidates: np.ndarray, todo: list[int], record: Callable[[list[tuple[int, float, str]]], None]) -> None:
        """Evaluate ``candidates[todo]``; ``record`` gets ``[(index, reward, error), ...]`` as results arrive."""
        if not todo:
            return
        if self.evaluate_batch is not None:
            try:
                values = list(self.evaluate_batch(candidates[todo]))
            except Exception as err:  # a failing batch: every episode of it failed
                record([(i, np.nan, _error_text(err)) for i in todo])
                return
            if len(values) != len(todo):
                raise ValueError(f"evaluate_batch returned {len(values)} rewards for {len(todo)} candidates")
            record([(i, *_as_reward(value)) for i, value in zip(todo, values)])
            return
        assert self.evaluate_episode is not None
        executor = self._get_executor()
        if executor is None:
            for i in todo:
                try:
                    value = self.evaluate_episode(candidates[i])
                except Exception as err:
                    record([(i, np.nan, _error_text(err))])
                else:
                    record([(i, *_as_reward(value))])
            return
        futures: dict[cf.Future, int] = {}
        try:
            for i in todo:
                futures[executor.submit(self.evaluate_episode, candidates[i])] = i
        except Exception as err:  # broken pool or shut-down executor: the remaining episodes fail
            submitted = set(futures.values())
            record([(i, np.nan, _error_text(err)) for i in todo if i not in submitted])
        broken = False
        try:
            for future in cf.as_completed(futures):
                i = futures[future]
                try:
                    value = future.result()
                except cf.BrokenExecutor as err:
                    broken = True
                    record([(i, np.nan, _error_text(err))])
                except Exception as err:
                    record([(i, np.nan, _error_text(err))])
                else:
                    record([(i, *_as_reward(value))])
        except BaseException:
            for future in futures:
                future.cancel()
            raise
        if broken and self._factory is not None:  # a worker died: start a fresh pool next time
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None


# ---------------------------------------------------------------------------------------------
# drivers
# ---------------------------------------------------------------------------------------------
def run_search(
    optimizer: Optimizer,
    evaluate_batch: Callable[[np.ndarray], Sequence[float]] | None = None,
    n_evaluations: int = 1000,
    out_dir: str | Path | None = None,
    callback: Callable[[GenerationInfo], bool | None] | None = None,
    *,
    evaluate_episode: Callable[[np.ndarray], float] | None = None,
    executor: ExecutorLike | None = None,
) -> LoopResult:
    """Maximise with ``optimizer`` until ``n_evaluations`` episodes are told or it stops.

    Evaluation is either ``evaluate_batch(candidates) -> rewards`` (one call per generation, e.g.
    a rollout executor's batch evaluation wrapped by :func:`batch_evaluator`; an exception
    instance in place of a reward fails that episode; if the call raises, the whole batch is
    failed) or
    ``evaluate_episode(params) -> reward`` (per episode, serially or through ``executor``: a
    :class:`concurrent.futures.Executor`, or a zero-argument factory of one, which the loop then
    owns and recreates when a worker dies). The last generation is always completed, so the count
    may exceed ``n_evaluations`` by less than one population. ``callback(info)`` runs after every
    generation; returning ``True`` stops the search. See the module docstring for ``out_dir``.
    """
    if n_evaluations < 1:
        raise ValueError(f"n_evaluations must be >= 1, got {n_evaluations}")
    evaluator = _Evaluator(evaluate_batch, evaluate_episode, executor)
    out = None if out_dir is None else Path(out_dir)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    optimizer, loop = _restore(optimizer, out)
    resumed = loop is not None
    generation = int(loop["generation"]) if loop else 0
    told = int(loop["n_evaluations"]) if loop else 0
    log = _EpisodeLog(None if out is None else out / EPISODES_FILE, optimizer.n_params, 0)
    resumed = resumed or bool(log.rows)
    stop_reason = "budget"
    empty = np.zeros(0)
    try:
        while told < n_evaluations:
            if optimizer.stop():
                stop_reason = "optimizer"
                break
            candidates = np.atleast_2d(np.asarray(optimizer.ask(), dtype=float))
            n = candidates.shape[0]
            raw, failed, done = log.replay(generation, candidates, None, out)

            def record(results: list[tuple[int, float, str]]) -> None:
                for i, reward, error in results:
                    raw[i], failed[i], done[i] = reward, bool(error), True
                log.append(*(_Row(generation, i, reward, bool(error), error, empty, candidates[i]) for i, reward, error in results))

            evaluator.run(candidates, [i for i in range(n) if not done[i]], record)
            optimizer.tell(candidates, np.where(failed, np.nan, raw))
            generation += 1
            told += n
            _save(optimizer, out, {"generation": generation, "n_evaluations": told})
            if callback is not None and callback(GenerationInfo(generation, candidates, raw, failed, told, optimizer)):
                stop_reason = "callback"
                break
    finally:
        evaluator.close()
    return log.result(optimizer, resumed, stop_reason, contextual=False)


def run_contextual_search(
    optimizer: ContextualOptimizer,
    evaluate: Callable[[np.ndarray, np.ndarray], float] | None,
    n_episodes: int,
    context_bounds: np.ndarray,
    out_dir: str | Path | None = None,
    callback: Callable[[GenerationInfo], bool | None] | None = None,
    *,
    evaluate_batch: Callable[[np.ndarray, np.ndarray], Sequence[Any]] | None = None,
    batch_size: int = 1,
) -> LoopResult:
    """Contextual policy search: per episode, ``s = optimizer.select_context(context_bounds)``,
    ``theta = optimizer.ask(s)``, ``reward = evaluate(s, theta)``, ``optimizer.tell(s, theta, reward)``.

    With ``batch_size > 1``, ``batch_size`` episodes are asked before they are evaluated and told
    (for parallel rollouts; meant for optimizers whose ``ask`` does not need the unreported
    episodes, such as C-REPS, which updates only every ``n_samples_per_update`` episodes), and
    ``evaluate_batch(contexts, params) -> rewards`` (arrays of shape ``(k, n_context)``,
    ``(k, n_params)``; an exception instance in place of a reward fails that episode) may replace
    ``evaluate``. Episodes are recorded (with their context) as they are evaluated and the state is
    saved after every batch; the batch number is the ``generation`` column (the episode number when
    ``batch_size == 1``). Failures and resume as in :func:`run_search`.
    """
    if n_episodes < 1:
        raise ValueError(f"n_episodes must be >= 1, got {n_episodes}")
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    if (evaluate is None) == (evaluate_batch is None):
        raise ValueError("give exactly one of evaluate or evaluate_batch")
    bounds = np.asarray(context_bounds, dtype=float)
    if bounds.shape != (optimizer.n_context, 2) or not np.isfinite(bounds).all() or (bounds[:, 0] >= bounds[:, 1]).any():
        raise ValueError(f"context_bounds must be a finite ({optimizer.n_context}, 2) array with lower < upper")
    out = None if out_dir is None else Path(out_dir)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    optimizer, loop = _restore(optimizer, out)
    generation = int(loop["generation"]) if loop else 0
    told = int(loop["n_evaluations"]) if loop else 0
    log = _EpisodeLog(None if out is None else out / EPISODES_FILE, optimizer.n_params, optimizer.n_context)
    resumed = loop is not None or bool(log.rows)
    stop_reason = "budget"
    # the shared evaluation of run_search, on joint rows (context, params)
    nc = optimizer.n_context
    evaluator = _Evaluator(
        None if evaluate_batch is None else lambda rows: evaluate_batch(rows[:, :nc], rows[:, nc:]),
        None if evaluate is None else lambda row: evaluate(row[:nc], row[nc:]),
        None,
    )
    while told < n_episodes:
        k = min(batch_size, n_episodes - told)
        contexts = np.zeros((k, optimizer.n_context))
        params = np.zeros((k, optimizer.n_params))
        for i in range(k):
            contexts[i] = np.asarray(optimizer.select_context(bounds), dtype=float).ravel()
            params[i] = np.asarray(optimizer.ask(contexts[i]), dtype=float).ravel()
        raw, failed, done = log.replay(generation, params, contexts, out)

        def record(results: list[tuple[int, float, str]]) -> None:
            for i, reward, error in results:
                raw[i], failed[i] = reward, bool(error)
            log.append(*(_Row(generation, i, reward, bool(error), error, contexts[i], params[i]) for i, reward, error in results))

        evaluator.run(np.hstack([contexts, params]), [i for i in range(k) if not done[i]], record)
        for i in range(k):
            optimizer.tell(contexts[i], params[i], np.nan if failed[i] else float(raw[i]))
        generation += 1
        told += k
        _save(optimizer, out, {"generation": generation, "n_evaluations": told})
        if callback is not None and callback(GenerationInfo(generation, params, raw, failed, told, optimizer, contexts)):
            stop_reason = "callback"
            break
    return log.result(optimizer, resumed, stop_reason, contextual=True)
