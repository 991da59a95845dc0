"""Model-based experiment design: the plans whose log tells the registry's causes apart best.

The task's designed experiment (:meth:`~besdrake.diagnosis.trials.TrialModel.design_experiments`) spreads its plans
at random over ranges that show every cause. Which spread tells causes apart depends on how each cause moves each
observable for each plan, and that the simulation knows before anything is logged. Locally optimal Bayesian design
(D-optimality, Chaloner & Verdinelli 1995): for a candidate plan ``p`` the sensitivities ``J_p`` of its observables
to every registry parameter (:func:`~besdrake.diagnosis.identifiability.scaled_sensitivities`: per unit of the
parameter's realistic range, per unit of the observable's typical noise, at nominal) give its information
``F_p = J_p J_p^T``; a log's information is ``PRIOR_PRECISION * I + sum F_p`` and the design maximises its log
determinant. Unlike each parameter's own signal, the determinant counts a parameter only for what no other parameter
explains (its *conditional* information), which is what a second hidden effect beside a first needs. Greedy
selection (log det is submodular: the greedy set is within 1 - 1/e of the best).

The candidates are the task's own random designs for :data:`POOL_DESIGNS` seeds (:func:`design_pool`): plans that
every design holds (a task's fixed plans, e.g. probes) keep the multiplicity they have there, the others form the
pool, whose sensitivities are computed once per registry, scenario and pool (about ``2 x parameters x pool`` rollouts)
and cached as ``.npz`` (:func:`cache_dir`). A design (:func:`optimal_plans`) chooses its distinct plans greedily from
a seeded share :data:`CANDIDATE_SHARE` of the pool (other seeds, other designs), repeats a seeded choice of them as the
task's design would, and shuffles the log. A log that will record only some observable groups (e.g. the outcome
alone) is designed on their features (``groups``). :attr:`OptimalDesign.gain` compares each parameter's conditional
information with the task's random design of the pool's first seed.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from besdrake._io import save_npz
from besdrake.diagnosis.identifiability import STEP_FRACTION, scaled_sensitivities
from besdrake.diagnosis.identifiability import cache_dir as identifiability_cache_dir
from besdrake.sim.effects import get_effect

#: Prior precision per parameter in units of its realistic range (a prior SD of half the range): keeps the log
#: determinant finite where no plan separates two parameters (structural classes) without weighing them.
PRIOR_PRECISION = 4.0
#: Random designs of the task pooled as candidates (their distinct non-fixed plans).
POOL_DESIGNS = 12
#: Share of the pool a design chooses from (drawn with its seed).
CANDIDATE_SHARE = 0.5
#: Bump when the computation changes (invalidates cached pools).
VERSION = 2


@dataclass
class DesignPool:
    """Candidate plans and their information blocks (``(N, P, P)``), the fixed plans with their multiplicity and
    information, the parameter keys, and the task design the pool's first seed gives (for comparison)."""

    candidates: list
    blocks: np.ndarray
    fixed: list[tuple[object, int]]
    fixed_info: np.ndarray
    keys: list[str]
    reference: list[int]
    reference_repeats: list[int]


@dataclass
class OptimalDesign:
    """A designed log (``plans``, shuffled), its log determinant, and per parameter key the ratio of its conditional
    information (given every other parameter) to the random reference design's."""

    plans: list
    log_det: float
    reference_log_det: float
    gain: dict[str, float]

    def median_gain(self) -> float:
        vals = [v for v in self.gain.values() if np.isfinite(v)]
        return float(np.median(vals)) if vals else float("nan")


def information(blocks: np.ndarray, counts: dict[int, int], base: np.ndarray) -> np.ndarray:
    """``base`` plus ``count`` times each chosen block."""
    M = base.copy()
    for i, c in counts.items():
        M += c * blocks[i]
    return M


def conditional_information(M: np.ndarray) -> np.ndarray:
    """Each parameter's information given every other one (1 / the diagonal of ``M``'s inverse), less the prior."""
    return 1.0 / np.diag(np.linalg.inv(M)) - PRIOR_PRECISION


def greedy_d_optimal(blocks: np.ndarray, base: np.ndarray, k: int, allowed: Sequence[int] | None = None) -> list[int]:
    """``k`` distinct indices of ``blocks`` (among ``allowed``), each the one that raises ``log det(base + sum)``
    most; fewer when fewer are allowed."""
    left = list(range(len(blocks))) if allowed is None else [int(i) for i in allowed]
    M, chosen = base.copy(), []
    for _ in range(min(k, len(left))):
        gains = [np.linalg.slogdet(M + blocks[i])[1] for i in left]
        best = left.pop(int(np.argmax(gains)))
        chosen.append(best)
        M += blocks[best]
    return chosen


def cache_dir() -> Path:
    """``$BESDRAKE_CACHE/design`` (default ``~/.cache/besdrake/design``), beside the identifiability cache."""
    return identifiability_cache_dir().parent / "design"


def _split_pool(designs: list[list]) -> tuple[list, list[tuple[object, int]], list[int], list[int]]:
    """Distinct candidate plans (in first-seen order), the fixed plans (in every design) with their multiplicity in
    the first, and the first design's distinct non-fixed plans and repeats as candidate indices."""
    from besdrake.transfer.measurement import plan_hash

    hashes = [[plan_hash(p) for p in d] for d in designs]
    common = set(hashes[0]).intersection(*map(set, hashes[1:]))
    fixed, seen = [], set()
    for p, h in zip(designs[0], hashes[0]):
        if h in common and h not in seen:
            seen.add(h)
            fixed.append((p, hashes[0].count(h)))
    candidates, index = [], {}
    for j, (d, hs) in enumerate(zip(designs, hashes)):
        for p, h in zip(d, hs):
            if h not in common and h not in index:
                index[h] = len(candidates)
                p.meta["name"] = f"{p.meta.get('name', 'plan')}_{j}"  # names are per design; unique in the pool
                candidates.append(p)
    first = [index[h] for h in hashes[0] if h not in common]
    distinct = list(dict.fromkeys(first))
    repeats = [i for i in distinct for _ in range(first.count(i) - 1)]
    return candidates, fixed, distinct, repeats


def _per_plan(J: np.ndarray, n_plans: int) -> np.ndarray:
    """The stacked sensitivities (P, N x F) as (N, P, F); NaN counts as 0 (a failed rollout tells nothing)."""
    J = np.nan_to_num(np.asarray(J, dtype=float))
    return J.reshape(J.shape[0], n_plans, J.shape[1] // n_plans).transpose(1, 0, 2)


def blocks_of(per_plan: np.ndarray, columns: Sequence[int] | None = None) -> np.ndarray:
    """Per plan the information block ``J_p J_p^T`` (N, P, P) of the features ``columns`` (default all)."""
    J = per_plan if columns is None else per_plan[:, :, list(columns)]
    return np.einsum("npf,nqf->npq", J, J)


def _cache_key(effects: Sequence[str], scen, plans: Sequence) -> str:
    from besdrake.transfer.measurement import plan_hash

    blob = json.dumps({"effects": [get_effect(e).describe() for e in effects], "scenario": scen.to_dict(), "version": VERSION,
                       "step": STEP_FRACTION, "plans": [plan_hash(p) for p in plans]}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _sensitivities(executor, effects: Sequence[str], plans: list, model, scen, use_cache: bool) -> tuple[list[str], np.ndarray]:
    """Parameter keys and the per-plan sensitivities (N, P, F) of ``plans``, from the cache when it holds them."""
    path = cache_dir() / f"{_cache_key(effects, scen, plans)}.npz"
    if use_cache and path.is_file():
        try:
            with np.load(path) as z:
                return [str(k) for k in z["keys"]], np.asarray(z["per_plan"], dtype=float)
        except (OSError, ValueError, KeyError):
            pass  # a damaged cache file is recomputed
    keys, J = scaled_sensitivities(executor, effects, plans, model)
    per_plan = _per_plan(J, len(plans))
    if use_cache:
        try:
            save_npz(path, keys=np.array(keys), per_plan=per_plan)  # atomic: concurrent designs each replace it whole
        except OSError:
            pass
    return keys, per_plan


def design_pool(n: int, repeats: int, scenario="nominal", effects: Sequence[str] | None = None, executor=None,
                use_cache: bool = True, groups: Sequence[str] | None = None, design_options: dict | None = None) -> DesignPool:
    """The candidates of an ``n``-plan design with ``repeats`` repeats on ``scenario`` (see the module docstring);
    ``effects``: the registry's that act on the scenario's task by default; ``groups``: the observable groups the log
    will record (default every one; e.g. the outcome alone); ``design_options``: the task's design options (keywords of its
    :meth:`~besdrake.diagnosis.trials.TrialModel.design_experiments`)."""
    from besdrake.diagnosis.trials import model_for
    from besdrake.sim.executors import make_executor
    from besdrake.sim.scenario import Scenario, load_scenario
    from besdrake.task import DEFAULT_TASK, effects_for

    scen = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    model = model_for(scen)
    sl = model.slices()
    unknown = sorted(set(groups or ()) - set(sl))
    if unknown:
        raise ValueError(f"design_pool: unknown observable group(s) {unknown}; the task's: {list(sl)}")
    effects = list(effects) if effects is not None else effects_for(getattr(scen, "task", None) or DEFAULT_TASK)
    designs = [model.design_experiments(n, repeats, seed=j, limits=scen.robot.limits, **(design_options or {})) for j in range(POOL_DESIGNS)]
    candidates, fixed, reference, reference_repeats = _split_pool(designs)
    own = executor is None
    ex = executor or make_executor("serial", scenario=scen, limits="flag")
    try:
        plans = candidates + [p for p, _ in fixed]
        keys, per_plan = _sensitivities(ex, effects, plans, model, scen, use_cache)
    finally:
        if own:
            ex.close()
    blocks = blocks_of(per_plan, None if groups is None else [c for g in groups for c in range(sl[g].start, sl[g].stop)])
    nc = len(candidates)
    fixed_info = sum((c * blocks[nc + j] for j, (_, c) in enumerate(fixed)), np.zeros(blocks.shape[1:]))
    return DesignPool(candidates, blocks[:nc], fixed, fixed_info, keys, reference, reference_repeats)


def optimal_plans(n: int = 25, repeats: int = 8, seed: int = 0, scenario="nominal", effects: Sequence[str] | None = None,
                  executor=None, use_cache: bool = True, pool: DesignPool | None = None, groups: Sequence[str] | None = None,
                  design_options: dict | None = None) -> OptimalDesign:
    """A D-optimal ``n``-plan log with ``repeats`` repeats (see the module docstring), seeded with ``seed``;
    ``pool``: a :func:`design_pool` already built for the same request (else built with ``groups`` and
    ``design_options``). :class:`ValueError` for a bad request."""
    pool = pool or design_pool(n, repeats, scenario, effects, executor, use_cache, groups, design_options)
    rng = np.random.default_rng(seed)
    fixed_repeats = sum(c - 1 for _, c in pool.fixed)
    k = n - repeats - len(pool.fixed)
    k_rep = repeats - fixed_repeats
    if k < 1 or k_rep < 0 or k_rep > k or len(pool.candidates) < k:
        raise ValueError(f"optimal_plans: cannot choose {k} distinct plans and {k_rep} repeats from {len(pool.candidates)} candidates")
    base = PRIOR_PRECISION * np.eye(len(pool.keys)) + pool.fixed_info
    share = rng.choice(len(pool.candidates), size=max(k, int(round(CANDIDATE_SHARE * len(pool.candidates)))), replace=False)
    chosen = greedy_d_optimal(pool.blocks, base, k, sorted(share.tolist()))
    again = rng.choice(chosen, size=k_rep, replace=False).tolist() if k_rep else []
    counts = {i: 1 + again.count(i) for i in chosen}
    ref_counts = {i: 1 + pool.reference_repeats.count(i) for i in pool.reference}
    M, R = information(pool.blocks, counts, base), information(pool.blocks, ref_counts, base)
    gain = {key: float(g / r) if r > 0 else float("nan") for key, g, r in zip(pool.keys, conditional_information(M), conditional_information(R))}
    log = [pool.candidates[i] for i in chosen + again] + [p for p, c in pool.fixed for _ in range(c)]
    order = rng.permutation(len(log))
    return OptimalDesign([log[int(i)] for i in order], float(np.linalg.slogdet(M)[1]), float(np.linalg.slogdet(R)[1]), gain)


__all__ = ["optimal_plans", "design_pool", "greedy_d_optimal", "information", "conditional_information", "OptimalDesign", "DesignPool",
           "PRIOR_PRECISION", "POOL_DESIGNS", "CANDIDATE_SHARE"]
