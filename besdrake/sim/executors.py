"""Evaluate batches of motion plans: the one interface learning loops see.

``make_executor(backend, workers, scenario)`` returns an executor with ``evaluate(plans, effects=None)``
(``effects``: one ``{name: {param: value}}`` for all plans or a list with one per plan) that returns one
outcome of the scenario's task per plan, in order. Backends:

* ``"serial"``: one rollout black box of the scenario's task (:mod:`besdrake.task`) in this process.
* ``"process"``: a local ``multiprocessing`` pool, one Diagram per worker built once by the pool initializer
  and reused (Diagrams cannot be pickled; plans, effects and Outcomes travel between processes). The start
  method is "fork" where available (fast, and no ``if __name__ == "__main__"`` guard needed in scripts); the
  workers build their own Diagrams after the fork, so nothing of Drake's is shared. Pass
  ``start_method="spawn"`` if the calling process runs threads (e.g. a Meshcat server).
* ``"ray"``: Ray actors, one Diagram each, for clusters (``pip install 'besdrake[cluster]'``); ray is
  imported only when this backend is requested.

Every rollout starts from the same reset Context, so the same inputs give the same Outcomes on every
backend, in any order. Plans are validated in the caller's process (:class:`~besdrake.plan.PlanError`
raised there); anything unexpected inside a worker becomes an outcome flagged ``sim_failed``.
Executors are context managers: ``with make_executor("process", workers=2) as ex: ex.evaluate(plans)``.
"""

from __future__ import annotations

import gc
import math
import os
import time
from dataclasses import dataclass, field
from typing import Any, Sequence

from besdrake.plan import MotionPlan, PlanError
from besdrake.sim.effects import merge_effects
from besdrake.sim.scenario import Scenario, load_scenario

BACKENDS = ("serial", "process", "ray")


#: Pool sizes for which :meth:`ExecutorStats.to_dict` reports the share the batches could keep busy.
POOL_SIZES = (16, 64)


@dataclass
class ExecutorStats:
    """What an executor did: rollouts, wall time inside ``evaluate``, the workers' busy time (s) and the width
    (rollouts) of every batch it was given."""

    rollouts: int = 0
    wall_s: float = 0.0
    busy_s: float = 0.0
    workers: int = 1
    widths: list[int] = field(default_factory=list, repr=False)

    @property
    def busy_share(self) -> float | None:
        """Share of the workers' capacity spent simulating while ``evaluate`` ran (None before any call)."""
        return None if self.wall_s <= 0 else min(1.0, self.busy_s / (self.wall_s * max(1, self.workers)))

    def fill(self, workers: int) -> float | None:
        """Share of a pool of ``workers`` that the batches could keep busy at best (equal rollout times): a batch of
        ``n`` rollouts occupies ``ceil(n / workers)`` rounds of the whole pool. None before any batch."""
        slots = sum(math.ceil(n / workers) * workers for n in self.widths)
        return None if not slots else sum(self.widths) / slots

    def add(self, other: "ExecutorStats") -> None:
        """Add ``other``'s rollouts, times and batches (the larger pool's worker count is kept)."""
        self.rollouts += other.rollouts
        self.wall_s += other.wall_s
        self.busy_s += other.busy_s
        self.workers = max(self.workers, other.workers)
        self.widths += other.widths

    def to_dict(self) -> dict[str, Any]:
        share = self.busy_share
        out = {"rollouts": self.rollouts, "wall_s": round(self.wall_s, 3), "busy_s": round(self.busy_s, 3), "workers": self.workers,
               "busy_share": None if share is None else round(share, 3),
               "rollouts_per_s": None if self.wall_s <= 0 else round(self.rollouts / self.wall_s, 2)}
        if self.widths:
            out |= {"batches": len(self.widths), "width_mean": round(sum(self.widths) / len(self.widths), 2), "width_max": max(self.widths)}
            out |= {f"fill_{w}_workers": round(self.fill(w), 3) for w in POOL_SIZES}
        return out


class ExecutorError(RuntimeError):
    """An executor cannot be created or used (unknown backend, ray missing, closed executor)."""


def _failed(message: str, scenario: Scenario) -> Any:
    """A failed outcome of the scenario's task."""
    from besdrake.task import get_task

    return get_task(scenario.task).failed_outcome(message)


def _make_rollout(scenario: Scenario):
    """The rollout black box of the scenario's task (one Diagram)."""
    from besdrake.task import get_task

    return get_task(scenario.task).make_rollout(scenario)


def _run_batch(rollout, items: list[tuple[MotionPlan, dict | None]], limits: str) -> list[Any]:
    out = []
    for plan, eff in items:
        try:
            out.append(rollout.rollout(plan, effects=eff, limits=limits))
        except Exception as err:  # noqa: BLE001 - a worker must not die on one bad rollout
            out.append(_failed(f"rollout raised {type(err).__name__}: {err}", rollout.scenario))
    return out


class Executor:
    """Base class: validates inputs, splits work, keeps the order."""

    backend = ""

    def __init__(self, scenario: Scenario | str = "nominal", limits: str = "flag") -> None:
        self.scenario = load_scenario(scenario) if not isinstance(scenario, Scenario) else scenario
        if limits not in ("raise", "flag"):
            raise ValueError(f"limits must be 'raise' or 'flag', got {limits!r}")
        self.limits = limits
        self._closed = False
        self.stats = ExecutorStats()

    def _prepare(self, plans: Sequence[MotionPlan], effects) -> list[tuple[MotionPlan, dict | None]]:
        if self._closed:
            raise ExecutorError(f"{self.backend} executor is closed")
        plans = list(plans)
        for i, p in enumerate(plans):
            if not isinstance(p, MotionPlan):
                raise PlanError(f"plan {i} is a {type(p).__name__}, not a MotionPlan")
            try:
                p.validate()
                if self.limits == "raise":
                    rep = p.check_limits(self.scenario.robot.limits)
                    if (rep.position > 0).any():
                        raise PlanError(f"exceeds {self.scenario.robot.name}'s position limits: " + ", ".join(rep.violations()))
            except PlanError as err:
                raise PlanError(f"plan {i}: {err}") from err
        if effects is None or isinstance(effects, dict):
            effs = [effects] * len(plans)
        else:
            effs = list(effects)
            if len(effs) != len(plans):
                raise ValueError(f"got {len(effs)} effect dicts for {len(plans)} plans (give one dict or one per plan)")
        for e in effs:
            merge_effects(self.scenario.effects, e)  # raises EffectError here, not in a worker
        return list(zip(plans, effs))

    def evaluate(self, plans: Sequence[MotionPlan], effects: dict | list | None = None) -> list[Any]:
        """Simulate every plan (with its effects); Outcomes in the order of ``plans``."""
        items = self._prepare(plans, effects)
        if not items:
            return []
        t0 = time.perf_counter()
        out, busy = self._evaluate(items)
        self.stats.rollouts += len(items)
        self.stats.widths.append(len(items))
        self.stats.wall_s += time.perf_counter() - t0
        self.stats.busy_s += busy
        self.stats.workers = int(getattr(self, "workers", 1))
        return out

    def _evaluate(self, items) -> tuple[list[Any], float]:  # pragma: no cover - abstract
        """Outcomes in order, and the workers' busy seconds."""
        raise NotImplementedError

    def close(self) -> None:
        self._closed = True

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class SerialExecutor(Executor):
    """All rollouts in this process, one Diagram built on first use."""

    backend = "serial"

    def __init__(self, scenario: Scenario | str = "nominal", limits: str = "flag") -> None:
        super().__init__(scenario, limits)
        self._rollout = None

    def _evaluate(self, items):
        if self._rollout is None:
            self._rollout = _make_rollout(self.scenario)
        t0 = time.perf_counter()
        out = _run_batch(self._rollout, items, self.limits)
        return out, time.perf_counter() - t0


# ------------------------------------------------------------------------------------------ process pool
_WORKER_ROLLOUT = None
_WORKER_SCENARIO: Scenario | None = None
_WORKER_ERROR = ""


def _plugin_paths() -> list[str]:
    """The plugins loaded in this process whose files still exist (their effects and tasks must exist in every
    worker too; a forked worker has them all already, a spawned one loads these)."""
    from besdrake.plugins import loaded_plugin_paths

    return [str(p) for p in loaded_plugin_paths() if p.is_file()]


def _init_worker(scenario: Scenario, plugins: tuple[str, ...] = ()) -> None:
    """Pool initializer: load the caller's effect plugins and build this worker's Diagram once. A failure
    is kept and reported, not raised (a raising initializer would make the pool respawn workers forever)."""
    global _WORKER_ROLLOUT, _WORKER_SCENARIO, _WORKER_ERROR
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    _WORKER_SCENARIO = scenario
    try:
        from besdrake.plugins import load_plugins

        load_plugins(list(plugins))  # once per process: a forked worker has them already

        _WORKER_ROLLOUT = _make_rollout(scenario)
    except Exception as err:  # noqa: BLE001
        _WORKER_ERROR = f"{type(err).__name__}: {err}"


def _worker_batch(args) -> tuple[list[Any], float]:
    """A worker's batch: its Outcomes and the seconds it spent on them."""
    items, limits = args
    if _WORKER_ROLLOUT is None:
        return [_failed(f"worker has no simulation: {_WORKER_ERROR}", _WORKER_SCENARIO) for _ in items], 0.0
    t0 = time.perf_counter()
    out = _run_batch(_WORKER_ROLLOUT, items, limits)
    return out, time.perf_counter() - t0


def _chunks(items: list, workers: int) -> list[list]:
    """``items`` in consecutive chunks, about four per worker (load balance against per-chunk overhead)."""
    size = math.ceil(len(items) / min(len(items), workers * 4))
    return [items[i : i + size] for i in range(0, len(items), size)]


def _worker_ready(_=None) -> str:
    return "" if _WORKER_ROLLOUT is not None else (_WORKER_ERROR or "not initialised")


def default_start_method() -> str:
    """The process start method of besdrake's local pools: fork where available (workers inherit the loaded
    modules and plugins), else spawn."""
    import multiprocessing as mp

    return "fork" if "fork" in mp.get_all_start_methods() else "spawn"


class ProcessExecutor(Executor):
    """A local process pool; each worker builds its Diagram once (pool initializer) and reuses it.

    A worker that dies (killed, out of memory, a crash inside the simulator) does not hang the
    caller: ``multiprocessing.Pool`` replaces it but loses its task, so the executor watches the
    workers' process ids while it waits; when one changes, every episode of the batch comes back
    as a failed outcome (``sim_failed``, with the reason), the pool is rebuilt, and the next batch
    runs normally.
    """

    backend = "process"
    poll_s = 0.2

    def __init__(self, scenario: Scenario | str = "nominal", workers: int | None = None, limits: str = "flag", start_method: str | None = None) -> None:
        import multiprocessing as mp

        super().__init__(scenario, limits)
        self._context = mp.get_context(start_method or default_start_method())
        self.workers = int(workers or os.cpu_count() or 1)
        if self.workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self._start()

    def _start(self) -> None:
        # Collect garbage here, in the caller's thread: the pool's threads allocate while pickling, and a collection
        # there would destroy leftover Drake objects (e.g. a Meshcat) off their thread, which aborts the process.
        gc.collect()
        self._pool = self._context.Pool(self.workers, initializer=_init_worker, initargs=(self.scenario, tuple(_plugin_paths())))
        # Wait until every worker has built its Diagram, so timings exclude start-up.
        errors = [e for e in self._pool.map(_worker_ready, range(self.workers), chunksize=1) if e]
        if errors:
            self._pool.terminate()
            self._closed = True
            raise ExecutorError(f"a worker could not build the simulation: {errors[0]}")

    def _pids(self) -> set[int]:
        return {p.pid for p in self._pool._pool}  # Pool keeps its worker processes here

    def _evaluate(self, items):
        chunks = _chunks(items, self.workers)
        pids = self._pids()
        pending = self._pool.map_async(_worker_batch, [(c, self.limits) for c in chunks], chunksize=1)
        while not pending.ready():
            pending.wait(self.poll_s)
            if not pending.ready() and self._pids() != pids:  # a worker died and was replaced
                self._pool.terminate()
                self._start()
                return [_failed("a simulation worker died (killed or crashed) during this batch", self.scenario) for _ in items], 0.0
        done = pending.get()
        return [o for chunk, _ in done for o in chunk], sum(s for _, s in done)

    def close(self) -> None:
        if not self._closed:
            self._pool.close()
            self._pool.join()
        super().close()


# ------------------------------------------------------------------------------------------ ray
def _import_ray():
    try:
        import ray  # noqa: PLC0415
    except ImportError as err:
        raise ExecutorError("the 'ray' backend needs the ray package: pip install 'besdrake[cluster]'") from err
    return ray


def _ray_init_kwargs(kwargs: dict[str, Any], workers: int | None) -> dict[str, Any]:
    """``ray.init`` arguments: connect to ``address`` (e.g. "auto" or "HOST:PORT") when given; else start a
    private local Ray with ``workers`` CPUs, no dashboard (its web UI stays closed unless asked for) and the
    node address 127.0.0.1. Ray's own gRPC ports cannot be bound to one interface (Ray 2.60): they rely on
    Ray's token authentication, on by default."""
    kw = dict(kwargs)
    if kw.get("address") or os.environ.get("RAY_ADDRESS"):
        for key in ("num_cpus", "include_dashboard", "_node_ip_address"):
            kw.pop(key, None)
        kw.setdefault("log_to_driver", False)
        return kw
    kw.pop("address", None)
    kw.setdefault("include_dashboard", False)
    kw.setdefault("dashboard_host", "127.0.0.1")
    kw.setdefault("_node_ip_address", "127.0.0.1")
    kw.setdefault("log_to_driver", False)
    kw.setdefault("num_cpus", max(int(workers or 1), os.cpu_count() or 1))  # later executors may ask for more actors
    return kw


class RayExecutor(Executor):
    """Ray actors (one Diagram each) on the current Ray cluster (``ray.init`` if none is running)."""

    backend = "ray"

    def __init__(self, scenario: Scenario | str = "nominal", workers: int | None = None, limits: str = "flag", **init_kwargs: Any) -> None:
        ray = _import_ray()
        super().__init__(scenario, limits)
        if not ray.is_initialized():
            ray.init(**_ray_init_kwargs(init_kwargs, workers))
        self._ray = ray
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.workers = int(workers or max(1, cpus))
        if self.workers > cpus:  # an actor takes one CPU: the surplus would wait for one forever
            raise ExecutorError(f"the Ray cluster has {cpus} CPU(s), fewer than the {self.workers} workers asked for")

        @ray.remote(num_cpus=1)
        class _Actor:
            def __init__(self, scenario, plugins):
                _init_worker(scenario, plugins)

            def ready(self):
                return _worker_ready()

            def run(self, items, limits):
                return _worker_batch((items, limits))

        plugins = tuple(_plugin_paths())
        self._actors = [_Actor.remote(self.scenario, plugins) for _ in range(self.workers)]
        errors = [e for e in ray.get([a.ready.remote() for a in self._actors]) if e]
        if errors:
            self.close()
            raise ExecutorError(f"a Ray worker could not build the simulation: {errors[0]}")

    def _evaluate(self, items):
        refs = [self._actors[i % self.workers].run.remote(c, self.limits) for i, c in enumerate(_chunks(items, self.workers))]
        done = self._ray.get(refs)
        return [o for chunk, _ in done for o in chunk], sum(s for _, s in done)

    def close(self) -> None:
        if not self._closed:
            for a in self._actors:
                self._ray.kill(a)
        super().close()


def make_executor(backend: str = "serial", workers: int | None = None, scenario: Scenario | str = "nominal", limits: str = "flag", **kwargs: Any) -> Executor:
    """An executor for ``backend`` ("serial", "process", "ray"). ``limits``: "flag" (default: plans beyond the
    joint limits are simulated and flagged, as learning loops need) or "raise" (:class:`PlanError`)."""
    if backend == "serial":
        return SerialExecutor(scenario, limits=limits)
    if backend == "process":
        return ProcessExecutor(scenario, workers=workers, limits=limits, **kwargs)
    if backend == "ray":
        return RayExecutor(scenario, workers=workers, limits=limits, **kwargs)
    raise ExecutorError(f"unknown executor backend {backend!r}; choose one of {BACKENDS}")
