"""Where a refinement episode's time goes, from candidate to reward (issue 27's "cheap episodes").

:func:`run_episode_bench` refines one imitated throw for a few generations with the default search on a serial
executor (one process, so every part is measured on the same CPU clock) and times each part of every episode:

* ``dmp_rollout``: the DMP rollouts of a candidate (:meth:`~besdrake.imitation.DMPParameterization.motion_plan`;
  retiming may roll out a stretched candidate again);
* ``retime_limits``: the rest of :meth:`~besdrake.search.refinement.RefinementProblem.plan` (the scaling, the
  retiming's limit peaks, validation);
* ``simulation``: the rollout's simulation loop (Drake's ``AdvanceTo`` in chunks and the release checks between
  them; ``release_checks`` is the release checks' share of it);
* ``rollout_other``: the rest of the rollout (reset, plan swap, ball placement, the state log, the flight);
* ``executor``: the executor's own work (plan and effect checks) around the rollouts;
* ``reward``: the reward (limit penalty, distance);
* ``search``: everything else (CMA-ES, the search loop, the episode records).

``rollout_cpu_ms`` is the CPU time of the rollout itself (``rollout()`` of the same plans, in the same run), so
``ratio_to_rollout`` = episode / rollout is the episode's price over simulating its plan (target <= 2). The
default throw of ``besdrake bench rollout`` is timed in the same run too: it simulates far less (its initial hold
is skipped and the ball leaves the scoop about 0.2 s in), so the ratio to it mostly compares simulated seconds.
"""

from __future__ import annotations

import os
import time
from contextlib import ExitStack, contextmanager
from dataclasses import asdict, dataclass, field
from typing import Any, Iterator

import numpy as np

#: Issue 27: an episode costs at most twice its rollout.
TARGET_RATIO = 2.0
PARTS = ("dmp_rollout", "retime_limits", "simulation", "release_checks", "rollout_other", "executor", "reward", "search")


@dataclass
class EpisodeSplit:
    """CPU ms per episode of each part (:data:`PARTS`), the episode's total, and the ratios (see the module)."""

    n_episodes: int
    ms_per_episode: dict[str, float]
    episode_cpu_ms: float
    episode_wall_ms: float
    rollout_cpu_ms: float
    ratio_to_rollout: float
    sim_s_per_episode: float
    default_throw_cpu_ms: float
    default_throw_sim_s: float
    ratio_to_default_throw: float
    best_reward: float
    machine: dict[str, Any] = field(default_factory=dict)
    target_ratio: float = TARGET_RATIO

    @property
    def passed(self) -> bool:
        return self.ratio_to_rollout <= self.target_ratio

    def to_dict(self) -> dict[str, Any]:
        return asdict(self) | {"passed": self.passed}

    def table(self) -> str:
        """The split as lines of text."""
        lines = [f"{self.n_episodes} episodes, CPU ms per episode (wall {self.episode_wall_ms:.1f} ms):"]
        for k in PARTS:
            share = self.ms_per_episode[k] / self.episode_cpu_ms if self.episode_cpu_ms > 0 else float("nan")
            lines.append(f"  {k:15s} {self.ms_per_episode[k]:8.2f}  {share:6.1%}" + ("  (within simulation)" if k == "release_checks" else ""))
        lines.append(f"  {'episode':15s} {self.episode_cpu_ms:8.2f}")
        lines.append(f"rollout of the same plans {self.rollout_cpu_ms:.2f} ms ({self.sim_s_per_episode:.2f} s simulated): "
                     f"episode / rollout = {self.ratio_to_rollout:.2f}  target <= {self.target_ratio:g}  {'PASS' if self.passed else 'MISS'}")
        lines.append(f"default throw (bench rollout) {self.default_throw_cpu_ms:.2f} ms ({self.default_throw_sim_s:.2f} s simulated): "
                     f"episode / default throw = {self.ratio_to_default_throw:.2f}")
        return "\n".join(lines)


class _Clock:
    """CPU seconds and calls per key, and what the timed calls returned where asked."""

    def __init__(self) -> None:
        self.cpu: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self.sim_times: list[float] = []

    @contextmanager
    def patched(self, owner: Any, name: str, key: str) -> Iterator[None]:
        """Time every call of ``owner.name`` (an instance's or a class's method) under ``key`` while inside."""
        own = name in vars(owner)
        original = vars(owner)[name] if own else None
        bound = getattr(owner, name)

        def timed(*args, **kwargs):
            t0 = time.process_time()
            try:
                return bound(*args, **kwargs)
            finally:
                self.cpu[key] = self.cpu.get(key, 0.0) + time.process_time() - t0
                self.calls[key] = self.calls.get(key, 0) + 1

        setattr(owner, name, timed)
        try:
            yield
        finally:
            if own:
                setattr(owner, name, original)
            else:
                delattr(owner, name)


class _TimedReward:
    """The problem's reward, timed (the reward is called, so it cannot be patched on the instance)."""

    def __init__(self, reward, clock: _Clock) -> None:
        self._reward, self._clock = reward, clock

    def __call__(self, *args, **kwargs):
        t0 = time.process_time()
        try:
            return self._reward(*args, **kwargs)
        finally:
            self._clock.cpu["reward"] = self._clock.cpu.get("reward", 0.0) + time.process_time() - t0

    def __getattr__(self, name: str):
        return getattr(self._reward, name)


def _default_throw_cost(rollout, n: int = 8) -> tuple[float, float]:
    """Median CPU ms and simulated s of the default throw (bench rollout's sweep of amplitudes) on ``rollout``."""
    from besdrake.tasks.throwing.bench import AMPLITUDE_RANGE
    from besdrake.tasks.throwing.throws import default_throw

    cpu, sim = [], []
    for a in np.linspace(*AMPLITUDE_RANGE, n):
        plan = default_throw(amplitude=float(a))
        t0 = time.process_time()
        out = rollout.rollout(plan, limits="flag")
        cpu.append(time.process_time() - t0)
        sim.append(out.sim_time)
    return float(np.median(cpu) * 1e3), float(np.median(sim))


def run_episode_bench(problem, n_episodes: int = 60, seed: int = 0, out_dir=None) -> EpisodeSplit:
    """Refine ``problem`` (a :class:`~besdrake.search.refinement.RefinementProblem` of the throwing task) for
    ``n_episodes`` on a serial executor and split the episodes' CPU time (see the module docstring)."""
    from besdrake.search.refinement import refine
    from besdrake.sim.executors import make_executor

    clock = _Clock()
    with make_executor("serial") as ex:
        ex.evaluate([problem.plan(np.zeros(problem.n_params))])  # builds the Diagram (not timed)
        rollout = ex._rollout
        default_ms, default_sim = _default_throw_cost(rollout)
        reward, problem.reward = problem.reward, _TimedReward(problem.reward, clock)
        simulate = rollout._simulate

        def simulate_logged(*args, **kwargs):
            res = simulate(*args, **kwargs)
            clock.sim_times.append(args[2].sim_time)  # the Outcome: its simulated seconds
            return res

        try:
            rollout._simulate = simulate_logged
            with ExitStack() as stack:
                for owner, name, key in ((problem.parameterization, "motion_plan", "dmp_rollout"), (problem, "plan", "plan"),
                                         (rollout, "rollout", "rollout"), (rollout, "_simulate", "simulation"),
                                         (rollout, "_ball_outside", "release_checks"), (ex, "evaluate", "executor")):
                    stack.enter_context(clock.patched(owner, name, key))
                c0, w0 = time.process_time(), time.perf_counter()
                res = refine(problem, ex, n_episodes=n_episodes, seed=seed, out_dir=out_dir, stop_on_success=False)
                cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        finally:
            problem.reward = reward
            del rollout._simulate
    return _split(clock, res, cpu, wall, default_ms, default_sim)


def _split(clock: _Clock, res, cpu: float, wall: float, default_ms: float, default_sim: float) -> EpisodeSplit:
    """The per-episode figures from the clock's totals (nested parts subtracted from their callers)."""
    n = max(1, res.n_episodes)
    c = {k: clock.cpu.get(k, 0.0) * 1e3 / n for k in ("dmp_rollout", "plan", "rollout", "simulation", "release_checks", "executor", "reward")}
    ms = {
        "dmp_rollout": c["dmp_rollout"],
        "retime_limits": c["plan"] - c["dmp_rollout"],
        "simulation": c["simulation"],
        "release_checks": c["release_checks"],
        "rollout_other": c["rollout"] - c["simulation"],
        "executor": c["executor"] - c["rollout"],
        "reward": c["reward"],
    }
    episode = cpu * 1e3 / n
    ms["search"] = episode - c["plan"] - c["executor"] - c["reward"]
    rollouts = max(1, clock.calls.get("rollout", 0))
    rollout_ms = clock.cpu.get("rollout", 0.0) * 1e3 / rollouts
    try:
        load = list(os.getloadavg())
    except OSError:  # pragma: no cover
        load = []
    return EpisodeSplit(
        n_episodes=res.n_episodes, ms_per_episode={k: round(v, 3) for k, v in ms.items()}, episode_cpu_ms=episode,
        episode_wall_ms=wall * 1e3 / n, rollout_cpu_ms=rollout_ms, ratio_to_rollout=episode / rollout_ms,
        sim_s_per_episode=float(np.mean(clock.sim_times)) if clock.sim_times else float("nan"),
        default_throw_cpu_ms=default_ms, default_throw_sim_s=default_sim, ratio_to_default_throw=episode / default_ms,
        best_reward=float(res.best_reward), machine={"cpu_count": os.cpu_count(), "loadavg_1_5_15": load},
    )
