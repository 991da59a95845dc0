"""CMA-ES refinement of a grasp skill in simulation, with the project's resumable search loop.

As in the paper (section 5: the imitated grasp was refined in simulation with CMA-ES for 50-100 iterations before
it worked on the robot): the parameters are those of :class:`~besdrake.tasks.pick_and_place.parameters.GraspParameterization`
(goals, execution times, close lead; optionally the position DMPs' weights) in its normalised units, one candidate is
planned (:class:`~besdrake.tasks.pick_and_place.skill_plan.SkillPlanner`) and simulated
(:class:`~besdrake.tasks.pick_and_place.rollout.PickPlaceRollout`), and its reward is the outcome's (minus the box's
distance from its place, minus a penalty per failure).

On disk (``out_dir``): the loop's ``episodes.csv`` and optimizer state (a killed run resumes), ``details.csv`` (one
row per simulated episode, written before the optimizer is told: success, flags, place error, plan duration, IK lag)
and, at the end, ``result.json``, ``skill.json`` and ``plan.json`` of the best candidate. Each worker process builds
its Diagram once and keeps it (:func:`_episode`).
"""

from __future__ import annotations

import concurrent.futures as cf
import csv
import json
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from besdrake._io import write_json
from besdrake.search.cmaes import CMAES
from besdrake.search.loop import GenerationInfo, run_search
from besdrake.search.refinement import ParameterScaling
from besdrake.tasks.pick_and_place.imitation import GraspImitationError, GraspSkill
from besdrake.tasks.pick_and_place.parameters import GraspParameterization

DETAILS_FILE = "details.csv"
#: Reward (m) taken off a nominal success per box shift (of 4) under which it fails (``RefineSettings.box_jitter``).
FRAGILE_PENALTY = 0.02
#: Plans longer than this (s) are not simulated (reward -(2 + duration / 100)); the robot file's limit applies if lower.
MAX_PLAN_DURATION = 30.0
DETAIL_COLUMNS = ("key", "reward", "success", "message", "place_error_m", "plan_duration_s", "ik_lag_m", "cpu_s")


@dataclass
class RefineSettings:
    """How long and how wide the search runs (``sigma0`` in the parameterisation's normalised units)."""

    max_generations: int = 100
    popsize: int | None = None  # cma's default 4 + 3 ln n
    sigma0: float = 1.0
    weights: bool = False
    box_jitter: float = 0.0  # m: a nominal success must also succeed with the box this far off along x and y
    workers: int = 1
    seed: int = 0
    stop_on_success: bool = True


@dataclass
class RefineResult:
    """The search's outcome (rewards in minus metres; ``episodes_to_success``: None when none succeeded)."""

    success: bool
    best_reward: float
    best_message: str
    best_place_error_m: float
    episodes: int
    generations: int
    episodes_to_success: int | None
    stop_reason: str
    initial_success: bool
    initial_reward: float
    best_skill: dict[str, Any] = field(repr=False, default_factory=dict)

    def summary(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("best_skill")
        return d


class GraspEpisode:
    """Candidate (normalised parameters) -> skill -> plan -> rollout -> details; built once per process."""

    def __init__(self, skill: dict[str, Any], scenario: str, weights: bool, box_offset=None,
                 box_jitter: float = 0.0) -> None:
        from besdrake.sim.scenario import load_scenario
        from besdrake.tasks.pick_and_place.rollout import PickPlaceRollout
        from besdrake.tasks.pick_and_place.skill_plan import SkillPlanner

        self.rollout = PickPlaceRollout(load_scenario(scenario))
        self.box_offset = None if box_offset is None else np.array([box_offset[0], box_offset[1], 0.0])
        self.planner = SkillPlanner.for_rollout(self.rollout, box_offset=self.box_offset)
        self.box_jitter = float(box_jitter)
        self.param = GraspParameterization(GraspSkill.from_dict(skill), weights=weights)
        self.scaling = ParameterScaling(*self.param.scaling())
        self.max_duration = min(MAX_PLAN_DURATION, self.rollout.robot.safety.max_plan_duration)

    def __call__(self, x: np.ndarray) -> dict[str, Any]:
        t0 = time.process_time()
        try:
            sp = self.planner.plan(self.param.from_vector(self.scaling.to_theta(x)))
        except (GraspImitationError, ValueError) as err:
            return _row(t0, float("nan"), f"no plan: {err}")
        if sp.plan.duration > self.max_duration:  # not simulated: a plan this slow is refused (and costly)
            return _row(t0, -(2.0 + sp.plan.duration / 100.0),
                        f"plan too slow: {sp.plan.duration:.1f} s > {self.max_duration:.1f} s", sp)
        out = self.rollout.rollout(sp.plan, box_offset=self.box_offset)
        if out.success and self.box_jitter > 0:
            out = self._robust(sp, out)
        return _row(t0, out.reward, out.message, sp, bool(out.success), out.place_error)


    def _robust(self, sp, nominal):
        """``nominal`` if the plan also succeeds with the box ``box_jitter`` off along +-x and +-y (where perception
        may put it); else ``nominal`` turned into a failure flagged fragile, its reward lowered by
        :data:`FRAGILE_PENALTY` per failing shift (so a fragile success still ranks above a grasp that failed)."""
        base = np.zeros(3) if self.box_offset is None else self.box_offset
        failed = []
        for d in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            out = self.rollout.rollout(sp.plan, box_offset=base + self.box_jitter * np.array([d[0], d[1], 0.0]))
            if not out.success:
                failed.append(f"{d}: {out.message}")
        if failed:
            nominal.success = False
            nominal.reward -= FRAGILE_PENALTY * len(failed)
            nominal.message = (f"fragile: fails with the box {self.box_jitter * 100:.1f} cm off along "
                               + "; ".join(failed))
        return nominal


def _row(t0: float, reward: float, message: str, sp=None, success: bool = False,
         place_error: float = float("nan")) -> dict[str, Any]:
    """One ``details.csv`` row (``t0``: the episode's start, process CPU time; ``sp``: its SkillPlan, if any)."""
    return {"reward": float(reward), "success": success, "message": message, "place_error_m": float(place_error),
            "plan_duration_s": float("nan") if sp is None else float(sp.plan.duration),
            "ik_lag_m": float("nan") if sp is None else float(sp.ik.position_residual.max()),
            "cpu_s": time.process_time() - t0}


_EPISODES: dict[str, GraspEpisode] = {}


def _episode(skill: dict[str, Any], scenario: str, weights: bool, x: np.ndarray, scene=None) -> dict[str, Any]:
    """Evaluate ``x`` with this process's cached :class:`GraspEpisode` (built on first use); ``scene``: (box offset or
    None, box jitter)."""
    key = json.dumps([skill, scenario, weights, scene], sort_keys=True, default=float)
    if key not in _EPISODES:
        _EPISODES.clear()
        box_offset, jitter = scene or (None, 0.0)
        _EPISODES[key] = GraspEpisode(skill, scenario, weights, box_offset, jitter)
    return _EPISODES[key](x)


def _key(x: np.ndarray) -> str:
    return " ".join(f"{v:.12g}" for v in np.asarray(x, dtype=float))


class _Details:
    """``details.csv``: one row per simulated episode, flushed and fsynced before the optimizer is told."""

    def __init__(self, path: Path | None) -> None:
        self.path, self.rows = path, {}
        if path is not None and path.is_file():
            with open(path, newline="") as f:
                for row in csv.DictReader(f):
                    row["success"] = row["success"] == "True"
                    self.rows[row["key"]] = row

    def append(self, key: str, detail: dict[str, Any]) -> None:
        self.rows[key] = dict(detail, key=key)
        if self.path is None:
            return
        new = not self.path.is_file()
        with open(self.path, "a", newline="") as f:
            w = csv.DictWriter(f, fieldnames=DETAIL_COLUMNS)
            if new:
                w.writeheader()
            w.writerow({k: self.rows[key].get(k) for k in DETAIL_COLUMNS})
            f.flush()
            os.fsync(f.fileno())


def refine_grasp(skill: GraspSkill, scenario: str = "pick_and_place", out_dir: str | Path | None = None,
                 settings: RefineSettings | None = None, box_offset=None) -> RefineResult:
    """Refine ``skill`` (adapted to the scene: :meth:`SkillPlanner.adapt`) with CMA-ES in ``scenario``'s simulation;
    stops at the first successful episode (``stop_on_success``; 0 episodes when the skill as given succeeds) or after
    ``max_generations``. ``box_offset`` (dx, dy
    m): the box stands that far from the scene's place on the shelf (the skill adapted to that)."""
    box_offset = None if box_offset is None else [float(box_offset[0]), float(box_offset[1])]
    s = settings or RefineSettings()
    out = None if out_dir is None else Path(out_dir)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    skill_d = skill.to_dict()
    param = GraspParameterization(skill, weights=s.weights)
    scaling = ParameterScaling(*param.scaling())
    optimizer = CMAES(np.zeros(param.n_params), s.sigma0, np.random.default_rng(s.seed), popsize=s.popsize,
                      bounds=scaling.x_bounds)
    details = _Details(None if out is None else out / DETAILS_FILE)
    pool = cf.ProcessPoolExecutor(s.workers) if s.workers > 1 else None
    episode = (skill_d, scenario, s.weights, (box_offset, float(s.box_jitter)))
    initial = _evaluate([np.zeros(param.n_params)], episode, details, pool)[0]
    if s.stop_on_success and initial.get("success"):  # the imitated grasp works as it is: nothing to search
        if pool is not None:
            pool.shutdown()
        return _initial_result(initial, skill, out)

    def evaluate_batch(X: np.ndarray) -> list[float]:
        return [d["reward"] for d in _evaluate(X, episode, details, pool)]

    def callback(info: GenerationInfo) -> bool:
        return s.stop_on_success and any(details.rows.get(_key(x), {}).get("success") for x in info.candidates)

    try:
        loop = run_search(optimizer, evaluate_batch, n_evaluations=s.max_generations * optimizer.popsize0, out_dir=out,
                          callback=callback)
    finally:
        if pool is not None:
            pool.shutdown()
    return _result(loop, details, initial, lambda x: param.from_vector(scaling.to_theta(x)), out)


def _evaluate(X, episode: tuple, details: _Details, pool) -> list[dict[str, Any]]:
    """Details of every candidate (from ``details.csv`` when already simulated), new ones recorded; ``episode``:
    (skill dict, scenario, weights, scene) as :func:`_episode` takes them."""
    keys = [_key(x) for x in X]
    todo = [i for i, k in enumerate(keys) if k not in details.rows]
    skill_d, scenario, weights, scene = episode
    if pool is None:
        results = [_episode(skill_d, scenario, weights, np.asarray(X[i]), scene) for i in todo]
    else:
        results = list(pool.map(_episode, *zip(*[(skill_d, scenario, weights, np.asarray(X[i]), scene)
                                                  for i in todo])))
    for i, r in zip(todo, results):
        details.append(keys[i], r)
    return [{**details.rows[k], "reward": float(details.rows[k]["reward"])} for k in keys]


def _reward(row: dict) -> float:
    r = float(row.get("reward", "nan") or "nan")
    return r if np.isfinite(r) else -np.inf


def _initial_result(initial: dict, skill: GraspSkill, out: Path | None) -> RefineResult:
    """The result when the unrefined skill already succeeds (0 episodes of search)."""
    result = RefineResult(success=True, best_reward=float(initial["reward"]), best_message=str(initial["message"]),
                          best_place_error_m=float(initial.get("place_error_m", "nan") or "nan"), episodes=0,
                          generations=0, episodes_to_success=0, stop_reason="initial_success", initial_success=True,
                          initial_reward=float(initial["reward"]), best_skill=skill.to_dict())
    return _written(result, out)


def _result(loop, details: _Details, initial: dict, skill_of, out: Path | None) -> RefineResult:
    """The best episode (a successful one first, then the highest reward) and its skill (``skill_of(x)``), written
    to ``out``."""
    rows = [(details.rows.get(_key(x), {}), x) for x in loop.params]
    hits = [i for i, (r, _) in enumerate(rows) if r.get("success")]
    ranked = sorted(rows, key=lambda r: (not r[0].get("success", False), -_reward(r[0])))
    best, x_best = ranked[0] if ranked else (initial, np.zeros(loop.params.shape[1]))
    skill = skill_of(np.asarray(x_best, dtype=float))
    result = RefineResult(
        success=bool(best.get("success", False)), best_reward=float(best.get("reward", "nan")),
        best_message=str(best.get("message", "")), best_place_error_m=float(best.get("place_error_m", "nan") or "nan"),
        episodes=len(loop.params), generations=int(loop.generations.max()) + 1 if len(loop.generations) else 0,
        episodes_to_success=hits[0] + 1 if hits else None, stop_reason=loop.stop_reason,
        initial_success=bool(initial.get("success", False)), initial_reward=float(initial["reward"]),
        best_skill=skill.to_dict())
    return _written(result, out)


def _written(result: RefineResult, out: Path | None) -> RefineResult:
    """``result`` after writing ``result.json`` and ``skill.json`` (the best skill) into ``out`` (if any)."""
    if out is not None:
        write_json(out / "result.json", result.summary())
        write_json(out / "skill.json", result.best_skill)
    return result
