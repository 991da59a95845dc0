#!/usr/bin/env python3
"""Benchmark BO-CPS (UCB, entropy search) and ACES on the simulated throw; prints JSON figures.

Task (paper section 4): learn an upper-level policy ``theta = pi(s)`` for targets ``s`` in
``[1, 2.5] x [-1, 1]`` m with ``theta`` = (swing amplitude, joint-1 angle in rad) of
:func:`besdrake.tasks.throwing.throws.default_throw`. The paper's two meta-parameters are the execution time and
the goal of joint 1; the amplitude sets the swing (execution) time, ``T = sqrt(5.77 * 0.75 * amplitude /
accel)``, and the swing's extent. Reward: minus the squared
distance (m^2) between touchdown and target; a throw without touchdown is a failed episode (NaN).
After ``--episodes`` episodes the policy is evaluated on the paper's 16 test contexts
``{1.3, 1.6, 1.9, 2.2} x {-0.7, -0.2, 0.2, 0.7}``; the figure is the mean distance (cm) per run.

References measured in the same run: the untrained template (centre of the parameter box) and,
with ``--oracle``, the best throw per test context found by Nelder-Mead with 60 rollouts each (the
precision the simulated throw allows). Optimizer overhead (ask/tell/select_context, without the
simulation) is timed separately. ``--task quadratic`` runs the same loop on a cheap analytic
contextual problem (no simulation), for overhead timing.

    python3 scripts/bench_bo.py --methods es ucb aces --seeds 5 --episodes 80
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from besdrake.search.aces import ACES  # noqa: E402
from besdrake.search.bocps import BOCPS  # noqa: E402

CONTEXT_BOUNDS = np.array([[1.0, 2.5], [-1.0, 1.0]])
PARAM_BOUNDS = np.array([[0.15, 0.9], [-0.9, 0.9]])
TEST_CONTEXTS = np.array([[x, y] for x in (1.3, 1.6, 1.9, 2.2) for y in (-0.7, -0.2, 0.2, 0.7)])
PAPER_CM = {"es": 9.01, "ucb": 19.74}  # real robot, mean of 5 runs after 80 episodes (paper section 4.2)


class SimThrow:
    """Touchdown of the default throw in the Drake simulation."""

    def __init__(self) -> None:
        import logging

        logging.getLogger("drake").setLevel(logging.ERROR)
        from besdrake.sim.rollout import Rollout
        from besdrake.tasks.throwing.throws import default_throw

        self._rollout = Rollout("nominal")
        self._plan = default_throw
        self.sim_time = 0.0

    def touchdown(self, theta: np.ndarray) -> np.ndarray | None:
        start = time.perf_counter()
        outcome = self._rollout.rollout(self._plan(float(theta[0]), float(theta[1])), limits="flag")
        self.sim_time += time.perf_counter() - start
        return None if outcome.touchdown is None or outcome.flags.get("sim_failed") else np.asarray(outcome.touchdown)[:2]


class QuadraticThrow:
    """Analytic stand-in: a smooth invertible map from parameters to a landing point (no simulation)."""

    sim_time = 0.0

    def touchdown(self, theta: np.ndarray) -> np.ndarray:
        rng = 0.8 + 2.2 * (theta[0] - 0.15) / 0.75 + 0.3 * np.sin(3 * theta[0]) * theta[1] ** 2
        return rng * np.array([np.cos(theta[1] * (1.0 + 0.1 * theta[0])), np.sin(theta[1] * (1.0 + 0.1 * theta[0]))])


def reward(task, s: np.ndarray, theta: np.ndarray) -> float:
    td = task.touchdown(theta)
    return float("nan") if td is None else -float(np.sum((td - s) ** 2))


def distance_cm(task, s: np.ndarray, theta: np.ndarray) -> float:
    td = task.touchdown(theta)
    return float("nan") if td is None else 100.0 * float(np.linalg.norm(td - s))


def evaluate(task, policy) -> float:
    return float(np.mean([distance_cm(task, s, policy(s)) for s in TEST_CONTEXTS]))


def run(task, method: str, seed: int, episodes: int, checkpoints: list[int]) -> dict:
    rng = np.random.default_rng(seed)
    opt = ACES(CONTEXT_BOUNDS, PARAM_BOUNDS, rng=rng) if method == "aces" else BOCPS(
        CONTEXT_BOUNDS, PARAM_BOUNDS, method, rng=rng)
    overhead, curve = 0.0, {}
    for episode in range(1, episodes + 1):
        start = time.perf_counter()
        s = opt.select_context(CONTEXT_BOUNDS)
        theta = opt.ask(s)
        overhead += time.perf_counter() - start
        r = reward(task, s, theta)
        start = time.perf_counter()
        opt.tell(s, theta, r)
        overhead += time.perf_counter() - start
        if episode in checkpoints:
            curve[episode] = evaluate(task, opt.policy)
    start = time.perf_counter()
    opt.policy(TEST_CONTEXTS[0])
    policy_ms = 1e3 * (time.perf_counter() - start)
    return {"mean_distance_cm": curve[episodes], "curve_cm": curve, "overhead_s": overhead,
            "failed_episodes": int(opt.failed.sum()), "policy_call_ms": policy_ms}


def oracle(task) -> float:
    from scipy.optimize import minimize

    dists = []
    for s in TEST_CONTEXTS:
        start = np.array([0.15 + 0.4 * (np.hypot(*s) - 1.0) / 1.5, np.arctan2(s[1], s[0])])
        res = minimize(lambda t: distance_cm(task, s, np.clip(t, PARAM_BOUNDS[:, 0], PARAM_BOUNDS[:, 1])),
                       np.clip(start, PARAM_BOUNDS[:, 0], PARAM_BOUNDS[:, 1]), method="Nelder-Mead",
                       options={"maxfev": 60, "initial_simplex": None, "xatol": 1e-4, "fatol": 1e-3})
        dists.append(float(res.fun))
    return float(np.mean(dists))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--task", choices=["sim", "quadratic"], default="sim")
    parser.add_argument("--methods", nargs="+", default=["es", "ucb"], choices=["es", "ucb", "aces"])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--episodes", type=int, default=80)
    parser.add_argument("--oracle", action="store_true")
    args = parser.parse_args(argv)
    task = SimThrow() if args.task == "sim" else QuadraticThrow()
    checkpoints = sorted({e for e in (20, 40, 60, args.episodes) if e <= args.episodes})
    out: dict = {"task": args.task, "episodes": args.episodes, "seeds": args.seeds,
                 "untrained_cm": evaluate(task, lambda s: PARAM_BOUNDS.mean(axis=1))}
    if args.oracle:
        out["oracle_cm"] = oracle(task)
    for method in args.methods:
        runs = []
        for seed in range(args.seeds):
            runs.append(run(task, method, seed, args.episodes, checkpoints))
            print(f"{method} seed {seed}: {runs[-1]['mean_distance_cm']:.2f} cm, overhead {runs[-1]['overhead_s']:.1f} s",
                  file=sys.stderr, flush=True)
        d = np.array([r["mean_distance_cm"] for r in runs])
        out[method] = {
            "mean_distance_cm_per_run": [round(v, 3) for v in d],
            "mean_cm": float(np.mean(d)), "median_cm": float(np.median(d)),
            "curve_median_cm": {str(e): float(np.median([r["curve_cm"][e] for r in runs])) for e in checkpoints},
            "overhead_s_median": float(np.median([r["overhead_s"] for r in runs])),
            "policy_call_ms_median": float(np.median([r["policy_call_ms"] for r in runs])),
            "failed_episodes": [r["failed_episodes"] for r in runs],
            "paper_real_robot_mean_cm": PAPER_CM.get(method),
            "ratio_to_untrained": float(np.median(d) / out["untrained_cm"]),
        }
    out["sim_time_s_total"] = task.sim_time
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
