"""Rollouts per second and the workers' busy share with 1 and 2 local workers, process pool and Ray; and the
scheduler (:mod:`besdrake.sim.scheduler`): independent refinement runs one after the other or sharing the pool.

    python scripts/bench_ray.py                  # 48 throws per setting, then 2 CMA-ES runs of 30 episodes; JSON
    python scripts/bench_ray.py --plans 16 --backends process
    python scripts/bench_ray.py --runs 4 --episodes 40 --skip-batch   # only the scheduler part

Ray (``pip install 'besdrake[cluster]'``) connects to ``RAY_ADDRESS`` when set, else starts a private local
Ray (no dashboard, node address 127.0.0.1). Every backend must give the serial backend's touchdowns
(``identical_to_serial``); the scheduler's settings must write the same episodes (``identical_episodes``).
In the scheduler part, ``wall_s`` and ``busy_share`` count the whole search (the optimizer's own steps between
batches included, where a pool idles); ``width_mean``/``width_max`` are the rollouts per batch, and
``fill_16_workers``/``fill_64_workers`` the share of a 16- or 64-worker pool those batches could keep busy at best.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))


def _plans(n: int):
    import numpy as np

    from besdrake.tasks.throwing.throws import default_throw

    return [default_throw(amplitude=a, yaw=y) for a, y in zip(np.linspace(0.25, 0.45, n), np.linspace(-0.2, 0.2, n))]


def measure(backend: str, workers: int, plans, repeats: int = 2) -> dict:
    """Evaluate ``plans`` ``repeats`` times (the first batch also warms the workers up; only later ones count)."""
    from besdrake.sim import make_executor

    t0 = time.perf_counter()
    with make_executor(backend, workers=workers) as ex:
        start_s = time.perf_counter() - t0
        out = ex.evaluate(plans)  # warm-up
        ex.stats.__init__(workers=ex.stats.workers)
        for _ in range(repeats):
            out = ex.evaluate(plans)
        stats = ex.stats.to_dict()
    return stats | {"backend": backend, "start_s": round(start_s, 2), "touchdowns": [None if o.touchdown is None else list(map(float, o.touchdown)) for o in out]}


def _refine_jobs(runs: int, episodes: int, popsize: int, out: Path) -> list:
    """``runs`` independent CMA-ES refinements of the default throw (seeds 0..runs-1), each a job for the scheduler."""
    from besdrake.search.refinement import RefinementProblem, refine
    from besdrake.tasks.throwing.template_base import fitted_default_throw
    from besdrake.sim.scenario import load_scenario

    base = fitted_default_throw()
    base.execution_time = 2.3
    problem = RefinementProblem(load_scenario("nominal").robot, base)
    return [lambda ex, k=k: refine(problem, ex, episodes, seed=k, out_dir=out / f"run{k}", popsize=popsize, stop_on_success=False)
            for k in range(runs)]


def measure_scheduler(backend: str, workers: int, runs: int, episodes: int, popsize: int, concurrent: bool) -> dict:
    """``runs`` refinements on one pool, one after the other or concurrently (one merged batch per round)."""
    import hashlib
    import tempfile

    from besdrake.sim import make_executor
    from besdrake.sim.scheduler import run_concurrently
    from besdrake.tasks.throwing.throws import default_throw

    with tempfile.TemporaryDirectory() as tmp, make_executor(backend, workers=workers) as ex:
        ex.evaluate([default_throw()] * ex.stats.workers)  # warm-up
        ex.stats.__init__(workers=ex.stats.workers)
        jobs = _refine_jobs(runs, episodes, popsize, Path(tmp))
        t0 = time.perf_counter()
        if concurrent:
            run_concurrently(ex, jobs)
        else:
            for job in jobs:
                job(ex)
        wall = time.perf_counter() - t0
        stats = ex.stats.to_dict()
        digest = hashlib.sha256(b"".join((Path(tmp) / f"run{k}" / "episodes.csv").read_bytes() for k in range(runs))).hexdigest()
    return stats | {"backend": backend, "schedule": "concurrent" if concurrent else "one after the other", "wall_s": round(wall, 2),
                    "busy_share": round(min(1.0, stats["busy_s"] / (wall * stats["workers"])), 3),
                    "rollouts_per_s": round(stats["rollouts"] / wall, 2), "episodes_sha256": digest}


def scheduler_rows(backends: list[str], runs: int, episodes: int, popsize: int) -> list[dict]:
    """The scheduler part: every backend with 1 and 2 workers, runs one after the other and concurrently."""
    rows = []
    for backend in backends:
        for workers in (1, 2):
            for concurrent in (False, True):
                try:
                    rows.append(measure_scheduler(backend, workers, runs, episodes, popsize, concurrent))
                except Exception as err:  # noqa: BLE001 - e.g. ray not installed: reported, not fatal
                    rows.append({"backend": backend, "workers": workers, "concurrent": concurrent, "error": f"{type(err).__name__}: {err}"})
    digests = {r["episodes_sha256"] for r in rows if "episodes_sha256" in r}
    for r in rows:
        r.pop("episodes_sha256", None)
    return rows + [{"identical_episodes": len(digests) == 1}]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plans", type=int, default=48, help="throws per batch (default 48)")
    parser.add_argument("--repeats", type=int, default=2, help="timed batches after the warm-up (default 2)")
    parser.add_argument("--backends", nargs="+", default=["process", "ray"], choices=["process", "ray"])
    parser.add_argument("--runs", type=int, default=2, help="scheduler part: independent CMA-ES runs (default 2, as learn's refinement)")
    parser.add_argument("--episodes", type=int, default=30, help="scheduler part: episodes per run (default 30)")
    parser.add_argument("--popsize", type=int, default=10, help="scheduler part: CMA-ES population (default 10, as learn's)")
    parser.add_argument("--skip-batch", action="store_true", help="only the scheduler part")
    parser.add_argument("--skip-scheduler", action="store_true", help="only the batch part")
    args = parser.parse_args(argv)
    out: dict = {}
    if not args.skip_scheduler:
        out["scheduler"] = {"runs": args.runs, "episodes": args.episodes, "popsize": args.popsize,
                            "results": scheduler_rows(args.backends, args.runs, args.episodes, args.popsize)}
    if not args.skip_batch:
        out["batch"] = batch_rows(args)
    print(json.dumps(out, indent=1))
    return 0


def batch_rows(args: argparse.Namespace) -> dict:
    """One batch of ``args.plans`` throws on every backend with 1 and 2 workers, against the serial backend."""
    plans = _plans(args.plans)
    serial = measure("serial", 1, plans, args.repeats)
    rows = [serial]
    for backend in args.backends:
        for workers in (1, 2):
            try:
                rows.append(measure(backend, workers, plans, args.repeats))
            except Exception as err:  # noqa: BLE001 - e.g. ray not installed: reported, not fatal
                rows.append({"backend": backend, "workers": workers, "error": f"{type(err).__name__}: {err}"})
    serial_td = serial.pop("touchdowns")
    for r in rows[1:]:
        if "touchdowns" in r:
            r["identical_to_serial"] = r.pop("touchdowns") == serial_td
    return {"plans": args.plans, "repeats": args.repeats, "results": rows}


if __name__ == "__main__":
    raise SystemExit(main())
