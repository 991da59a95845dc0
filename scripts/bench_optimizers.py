"""Benchmark of the local policy-search optimizers; prints one JSON object.

Figures are medians over seeds. References are measured in the same run:

* CMA-ES wrapper vs ``cma`` used directly (same population, its own seeding): evaluations to the
  target (ratio ~1 means the wrapper changes nothing) and wall time per generation (overhead);
* REPS and PI2 vs CMA-ES on the same 5-D sphere from the same start (evaluations until the mean
  of the search distribution is within 1e-2 of the optimum), REPS and PI2 on 5-D Rosenbrock, and
  all three with 49 parameters (as many as the throwing DMP; sphere, reward reduced 1e-4 times);
* C-REPS: mean regret over the paper's 16 test contexts after a fixed number of episodes, passive
  (uniform contexts) vs active (bandit) context selection;
* the loop driver: seconds per episode with and without an ``out_dir`` (CSV row fsync + state).

Usage: ``python3 scripts/bench_optimizers.py [--seeds 5]``
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time

import cma
import numpy as np

from besdrake.search.cmaes import CMAES
from besdrake.search.creps import CREPS
from besdrake.search.loop import run_search
from besdrake.search.pi2 import PI2
from besdrake.search.reps import REPS
from besdrake.search.testfunctions import ContextualQuadratic, reward_of, rosenbrock, sphere

BOUNDS = np.array([[1.0, 2.5], [-1.0, 1.0]])
TEST_CONTEXTS = np.array([[x, y] for x in (1.3, 1.6, 1.9, 2.2) for y in (-0.7, -0.2, 0.2, 0.7)])


def wrapper_to_target(cost, x0, sigma0, seed, target, budget, restarts=0):
    opt = CMAES(x0, sigma0, np.random.default_rng(seed), restarts=restarts)
    start = time.perf_counter()
    generations = 0
    while opt.n_evaluations < budget and not opt.stop() and -opt.best[1] >= target:
        x = opt.ask()
        opt.tell(x, -cost(x))
        generations += 1
    return opt.n_evaluations if -opt.best[1] < target else np.nan, (time.perf_counter() - start) / max(generations, 1)


def raw_cma_to_target(cost, x0, sigma0, seed, target, budget):
    es = cma.CMAEvolutionStrategy(x0, sigma0, {"seed": seed + 1, "verbose": -9, "tolfun": 1e-11, "tolx": 1e-11})
    start = time.perf_counter()
    best = np.inf
    while es.countevals < budget and not es.stop() and best >= target:
        x = es.ask()
        f = cost(np.array(x))
        es.tell(x, list(f))
        best = min(best, float(np.min(f)))
    return es.countevals if best < target else np.nan, (time.perf_counter() - start) / max(es.countiter, 1)


def mean_to_optimum(opt, budget, tol=1e-2, cost=sphere, optimum=0.0):
    reward = reward_of(cost)
    while opt.n_evaluations < budget:
        x = opt.ask()
        opt.tell(x, reward(x))
        if np.linalg.norm(opt.mean - optimum) < tol:
            return opt.n_evaluations
    return np.nan


def creps_regret(seed, episodes, active):
    problem = ContextualQuadratic.random(4, 2, np.random.default_rng(100 + seed), condition=10.0)
    opt = CREPS(np.zeros(4), 2, 1.0, np.random.default_rng(seed), active=active, context_bounds=BOUNDS)
    for _ in range(episodes):
        s = opt.select_context(BOUNDS)
        theta = opt.ask(s)
        opt.tell(s, theta, problem.reward(s, theta))
    return float(np.mean(problem.regret(TEST_CONTEXTS, opt.policy(TEST_CONTEXTS))))


def med(values):
    values = np.asarray(values, dtype=float)
    return None if np.isnan(values).all() else float(np.nanmedian(values))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--creps-episodes", type=int, default=1000)
    args = parser.parse_args()
    seeds = range(args.seeds)
    out: dict[str, object] = {"seeds": args.seeds}

    for name, cost, x0, sigma0, target, budget in [
        ("sphere10", sphere, np.full(10, 3.0), 1.0, 1e-8, 3000),
        ("rosenbrock5", rosenbrock, np.zeros(5), 0.5, 1e-6, 20000),
    ]:
        ours = [wrapper_to_target(cost, x0, sigma0, s, target, budget, restarts=5) for s in seeds]
        raw = [raw_cma_to_target(cost, x0, sigma0, s, target, budget) for s in seeds]
        out[f"cmaes_{name}"] = {
            "target": target,
            "budget": budget,
            "evaluations_median": med([e for e, _ in ours]),
            "solved": int(np.sum(np.isfinite([e for e, _ in ours]))),
            "raw_cma_evaluations_median": med([e for e, _ in raw]),
            "ratio_evaluations_vs_raw_cma": (med([e for e, _ in ours]) or np.nan) / (med([e for e, _ in raw]) or np.nan),
            "seconds_per_generation": med([t for _, t in ours]),
            "overhead_ratio_vs_raw_cma": med([t for _, t in ours]) / med([t for _, t in raw]),
        }

    start5 = np.full(5, 2.0)
    cma_mean = []
    for s in seeds:
        opt = CMAES(start5, 1.0, np.random.default_rng(s))
        cma_mean.append(mean_to_optimum(opt, 6000))
    reps = [mean_to_optimum(REPS(start5, 1.0, np.random.default_rng(s)), 6000) for s in seeds]
    pi2 = [mean_to_optimum(PI2(start5, 1.0, np.random.default_rng(s)), 6000) for s in seeds]
    out["sphere5_mean_within_1e-2"] = {
        "cmaes_evaluations_median": med(cma_mean),
        "reps_evaluations_median": med(reps),
        "pi2_evaluations_median": med(pi2),
        "reps_ratio_vs_cmaes": med(reps) / med(cma_mean),
        "pi2_ratio_vs_cmaes": med(pi2) / med(cma_mean),
    }

    rosen_start = np.zeros(5)
    out["rosenbrock5_mean_within_1e-2"] = {
        name: med([mean_to_optimum(make(rosen_start, 0.25, np.random.default_rng(s)), 20000, cost=rosenbrock, optimum=np.ones(5)) for s in seeds])
        for name, make in (("reps_evaluations_median", REPS), ("pi2_evaluations_median", PI2))
    }

    d49 = {}
    for name, make, sigma in (("cmaes", CMAES, 0.5), ("reps", REPS, 0.25), ("pi2", PI2, 0.25)):
        evaluations = []
        for s in seeds:
            opt = make(np.ones(49), sigma, np.random.default_rng(s))
            reward = reward_of(sphere)
            while opt.n_evaluations < 30000 and opt.best[1] < -1e-4 * 49:
                x = opt.ask()
                opt.tell(x, reward(x))
            evaluations.append(opt.n_evaluations if opt.best[1] >= -1e-4 * 49 else np.nan)
        d49[f"{name}_evaluations_median"] = med(evaluations)
    d49["reps_ratio_vs_cmaes"] = d49["reps_evaluations_median"] / d49["cmaes_evaluations_median"]
    d49["pi2_ratio_vs_cmaes"] = d49["pi2_evaluations_median"] / d49["cmaes_evaluations_median"]
    out["sphere49_reward_reduced_1e-4"] = d49

    passive = [creps_regret(s, args.creps_episodes, False) for s in seeds]
    active = [creps_regret(s, args.creps_episodes, True) for s in seeds]
    out["creps_contextual_quadratic"] = {
        "episodes": args.creps_episodes,
        "mean_regret_median_passive": med(passive),
        "mean_regret_median_active_bandit": med(active),
        "ratio_active_vs_passive": med(active) / med(passive),
    }

    timings = {}
    for label, use_dir in (("memory", False), ("out_dir", True)):
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            run_search(CMAES(np.zeros(49), 0.1, np.random.default_rng(0)), reward_of(sphere), 600, out_dir=tmp if use_dir else None)
            timings[label] = (time.perf_counter() - start) / 600
    out["loop_49d_seconds_per_episode"] = {**timings, "ratio_out_dir_vs_memory": timings["out_dir"] / timings["memory"]}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
