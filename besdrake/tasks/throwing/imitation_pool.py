"""Imitation of many throws at once on a pool of worker processes (``besdrake learn``'s imitation stage).

Every throw is imitated on its own (:func:`~besdrake.tasks.throwing.imitation.imitate_throw`: synchronization frame,
IK, DMP, one nominal rollout, its files), so the throws are spread over the workers and the reports come back in the
order of the jobs: the same reports and files as imitating them one after the other. Each worker builds its own
embodiment mapping and rollout Diagram once (nothing of Drake's crosses a process boundary); the start method is the
simulation pool's (fork where available).
"""

from __future__ import annotations

import multiprocessing as mp
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from besdrake.mocap.preprocess import Preprocessed
from besdrake.tasks.throwing.imitation import ThrowReport, imitate_throw

#: This process's (mapping, rollout) per (process id, scenario), built on its first job (a forked worker builds its own).
_TOOLS: dict[tuple[int, str], tuple] = {}


@dataclass
class ThrowJob:
    """One throw to imitate: its name, index in its recording, the recording and its frames, whether to plot it."""

    name: str
    index: int
    pre: Preprocessed
    start_frame: int
    end_frame: int
    figure: bool = True


def _tools(scenario: str) -> tuple:
    """The embodiment mapping and rollout of ``scenario`` in this process (built once)."""
    key = (os.getpid(), scenario)
    if key not in _TOOLS:
        from besdrake.embodiment import EmbodimentMapping
        from besdrake.sim import Rollout
        from besdrake.sim.scenario import load_scenario

        _TOOLS.clear()
        _TOOLS[key] = (EmbodimentMapping(load_scenario(scenario).robot), Rollout(scenario))
    return _TOOLS[key]


def _run(job: ThrowJob, scenario: str, out_dir: Path | None) -> ThrowReport:
    mapping, rollout = _tools(scenario)
    return imitate_throw(job.name, job.index, job.pre, job.start_frame, job.end_frame, mapping, rollout, out_dir, job.figure)


def imitate_throws(jobs: list[ThrowJob], scenario: str, out_dir: Path | None = None, workers: int = 1) -> list[ThrowReport]:
    """Imitate and simulate every job in ``scenario`` on ``workers`` processes (1: in this process); the reports in
    the order of ``jobs``."""
    if workers <= 1 or len(jobs) <= 1:
        return [_run(job, scenario, out_dir) for job in jobs]
    from besdrake.sim.executors import default_start_method

    with ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=mp.get_context(default_start_method())) as pool:
        futures = [pool.submit(_run, job, scenario, out_dir) for job in jobs]
        return [f.result() for f in futures]
