"""Rollouts per second and the workers' busy share with 1 and 2 local workers, process pool and Ray.

    python scripts/bench_ray.py                  # 48 throws per setting, JSON
    python scripts/bench_ray.py --plans 16 --backends process

Ray (``pip install 'besdrake[cluster]'``) connects to ``RAY_ADDRESS`` when set, else starts a private local
Ray (no dashboard, node address 127.0.0.1). Every backend must give the serial backend's touchdowns
(``identical_to_serial``).
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plans", type=int, default=48, help="throws per batch (default 48)")
    parser.add_argument("--repeats", type=int, default=2, help="timed batches after the warm-up (default 2)")
    parser.add_argument("--backends", nargs="+", default=["process", "ray"], choices=["process", "ray"])
    args = parser.parse_args(argv)
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
    print(json.dumps({"plans": args.plans, "repeats": args.repeats, "results": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
