"""Refinement runs: :func:`refine` drives the search (:mod:`besdrake.search.refinement.optimizer`) through the resumable
search loop (:func:`besdrake.search.loop.run_search`), writing ``problem.json`` and the episode records beside the
loop's files, and returns a :class:`RefinementResult`; :func:`plot_learning_curves` draws runs."""

from __future__ import annotations

import json
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from besdrake._io import save_figure as _save_figure
from besdrake._io import write_json
from besdrake.imitation import DMP
from besdrake.search.refinement.optimizer import _scouting_defaults, _search_defaults, make_optimizer
from besdrake.search.refinement.problem import RefinementProblem
from besdrake.search.refinement.records import params_key, read_details
from besdrake.search.refinement.settings import (DEFAULT_PATIENCE, DEFAULT_POPSIZE, DEFAULT_SIGMA0, DETAILS_FILE, PROBLEM_FILE, STAGNATION_TOL,
                                                 SUCCESS_DISTANCE, RefinementError)


@dataclass(frozen=True)
class StallRule:
    """When a run has stalled: after at least ``after`` episodes its best objective (m: the distance, robust where
    checked, plus limit penalties) gained less than ``tol`` over its last ``episodes`` episodes. Measured on 20
    benchmark runs (REFINEMENT.md, "A stall rule"): 200 / 1 cm / 400 stops 6, saves 1,260 of 13,090 episodes, and no run
    that reaches 0.1 m loses it; two failed runs end farther off than they would have (0.246 / 0.207 m instead of
    0.152 / 0.155 m). ``beyond`` (m): only while the best is still farther than this (0: always), a rule for runs that
    stall far from their goal."""

    episodes: int = 200
    tol: float = 0.01
    after: int = 400
    beyond: float = 0.0

    def __post_init__(self) -> None:
        if int(self.episodes) != self.episodes or self.episodes < 1 or int(self.after) != self.after or self.after < 0:
            raise RefinementError(f"stall episodes must be >= 1 and after >= 0 (whole numbers), got {self.episodes!r}, {self.after!r}")
        if not (np.isfinite(self.tol) and self.tol >= 0):
            raise RefinementError(f"stall tol must be a distance >= 0 (m), got {self.tol!r}")
        if not (np.isfinite(self.beyond) and self.beyond >= 0):
            raise RefinementError(f"stall beyond must be a distance >= 0 (m), got {self.beyond!r}")

    def stalled(self, objectives: Sequence[float]) -> bool:
        """Whether a run whose episodes scored ``objectives`` (m, in order; NaN: failed) has stalled."""
        o = np.asarray(objectives, dtype=float)
        n = len(o)
        if n < max(int(self.after), int(self.episodes) + 1):
            return False
        best = np.minimum.accumulate(np.where(np.isfinite(o), o, np.inf))
        return bool(best[n - 1 - int(self.episodes)] - best[-1] < self.tol and best[-1] > self.beyond)


@dataclass(frozen=True)
class AnyStall:
    """Stalled as soon as one of ``rules`` (:class:`StallRule`) says so: e.g. the usual rule and a quicker one for a run
    that stays far from its goal."""

    rules: tuple[StallRule, ...]

    @classmethod
    def of(cls, *rules: StallRule | None) -> StallRule | AnyStall | None:
        """The given rules (None: left out) as one: None, the only rule, or an :class:`AnyStall` of them."""
        given = tuple(rule for rule in rules if rule is not None)
        return cls(given) if len(given) > 1 else (given[0] if given else None)

    def stalled(self, objectives: Sequence[float]) -> bool:
        """Whether a run whose episodes scored ``objectives`` (m, in order; NaN: failed) has stalled by any rule."""
        return any(rule.stalled(objectives) for rule in self.rules)


@dataclass
class RefinementResult:
    """Outcome of one refinement run (distances in m, times in s)."""

    best_theta: np.ndarray
    best_reward: float
    best_distance: float
    best_touchdown: tuple[float, float] | None
    success: bool
    episodes_to_success: int | None
    n_episodes: int
    n_failed: int
    wall_time: float
    rewards: np.ndarray
    distances: np.ndarray
    successes: np.ndarray
    penalties: np.ndarray = field(default_factory=lambda: np.zeros(0))
    resumed: bool = False
    stop_reason: str = "budget"
    #: restart attempts of a :class:`~besdrake.search.cmaes.StagnationRestartCMAES` run (finished ones), else empty
    attempts: list[dict[str, Any]] = field(default_factory=list)
    #: RMS distance over the setup's scatter per episode (NaN where no robust check ran) and the rollouts of each check
    robust_distances: np.ndarray = field(default_factory=lambda: np.zeros(0))
    robust_rollouts: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    best_robust_distance: float = float("nan")
    robust: bool = False
    #: the DMP of the best episode (of the imitated movement it varies: :class:`RefinementProblem`'s families)
    best_dmp: DMP | None = None

    @property
    def n_robust_rollouts(self) -> int:
        """Rollouts spent on robust checks (the price of robustness; the episodes' own rollouts not counted)."""
        return int(self.robust_rollouts.sum())

    def reached(self, stop_distance: float = SUCCESS_DISTANCE) -> bool:
        """Whether an episode of this run ends a run that stops on success (:func:`stops_at`'s rule: a successful
        episode within ``stop_distance``, by its robust distance where one was checked)."""
        d = self.distances
        if self.robust_distances.size == d.size:
            d = np.where(np.isfinite(self.robust_distances), self.robust_distances, d)
        return bool(np.any(self.successes & (d < stop_distance)))

    def best_so_far(self) -> np.ndarray:
        """Best target distance (m) of the episodes within every limit, up to each episode (NaN before the first)."""
        valid = np.isfinite(self.distances) & (self.penalties == 0.0) if self.penalties.size == self.distances.size else np.isfinite(self.distances)
        d = np.where(valid, self.distances, np.inf)
        best = np.minimum.accumulate(d) if d.size else d
        return np.where(np.isfinite(best), best, np.nan)

    def summary(self) -> dict[str, Any]:
        return {
            "success": self.success,
            "episodes_to_success": self.episodes_to_success,
            "best_distance_m": None if not np.isfinite(self.best_distance) else self.best_distance,
            "best_distance_within_limits_m": (float(np.nanmin(self.best_so_far())) if np.isfinite(self.best_so_far()).any() else None),
            "best_reward": None if not np.isfinite(self.best_reward) else self.best_reward,
            "best_touchdown_m": None if self.best_touchdown is None else list(self.best_touchdown),
            "n_episodes": self.n_episodes,
            "n_failed": self.n_failed,
            "wall_time_s": self.wall_time,
            "resumed": self.resumed,
            "stop_reason": self.stop_reason,
            "n_restarts": len(self.attempts),
        } | ({"robust_rollouts": self.n_robust_rollouts,
              "best_robust_distance_m": None if not np.isfinite(self.best_robust_distance) else self.best_robust_distance}
             if self.robust else {})


def refine(
    problem: RefinementProblem,
    executor,
    n_episodes: int = 2000,
    seed: int = 0,
    out_dir: str | Path | None = None,
    sigma0: float = DEFAULT_SIGMA0,
    popsize: int = DEFAULT_POPSIZE,
    stop_on_success: bool = True,
    progress: Callable[[int, float, float], None] | None = None,
    optimizer=None,
    *,
    meta_episodes: int = 0,
    meta_sigma: float = 1.0,
    stagnation_generations: int | None = None,
    starts: np.ndarray | None = None,
    restart_from_best: bool = True,
    stagnation_tol: float = STAGNATION_TOL,
    max_attempt_generations: int = 0,
    cma_options: dict[str, Any] | None = None,
    popsize_growth: float | None = None,
    restart_regimes: str | None = None,
    small_share: float = 1.0,
    patience: int = DEFAULT_PATIENCE,
    scouts: int | None = None,
    scout_generations: int | None = None,
    scout_halving: bool | None = None,
    stop_distance: float | None = None,
    stall: StallRule | AnyStall | None = None,
    switch_distance: float | None = None,
    next_starts: np.ndarray | None = None,
    race_stall: StallRule | None = None,
) -> RefinementResult:
    """Refine ``problem`` with CMA-ES for at most ``n_episodes`` episodes (stops at the first
    generation with a success when ``stop_on_success``). With ``out_dir`` the run is resumable:
    calling again with the same folder continues it (see :mod:`besdrake.search.loop`).
    ``progress(n_episodes, best_distance, generation_wall_time)`` is called after each generation.
    ``meta_episodes``/``meta_sigma``: the meta-parameter stage of :func:`make_optimizer` (0: none).
    ``stop_distance`` (m, default :data:`SUCCESS_DISTANCE`): with ``stop_on_success``, stop only at a success whose
    distance (its robust distance where a robust check ran) is below it: a margin inside the goal. ``stall``: end the
    run early once it has stalled (:class:`StallRule` or :class:`AnyStall`; decided from the episode log, so a resumed
    run decides the same); its result's ``stop_reason`` is then ``"stalled"``. ``switch_distance`` (m): a raced scout
    that went on and stalled farther than this hands over to the next scout the race eliminated (:func:`make_optimizer`); ``next_starts``: start
    points of further races, one raced where the race's winner ends farther than that (:func:`make_optimizer`);
    ``race_stall`` (a :class:`StallRule`; needs ``next_starts``): the next group is raced also where the current race has
    stalled by that rule (its ``after`` counted from the race's start, its ``beyond`` the distance the run's best must
    still be off), and ``stall`` then judges the current race alone (from where it began). ``scout_generations``
    None: the rung length the run in ``out_dir`` began with, else :data:`DEFAULT_SCOUT_GENERATIONS` (a killed run resumes
    with its own race after the default changed)."""
    from besdrake.search.loop import run_search

    if scout_generations is None:  # a run keeps the race it began with where the default has changed since (4 -> 3)
        scout_generations = _saved_scout_generations(None if out_dir is None else Path(out_dir))
    settings = _checked_settings(n_episodes, meta_episodes, meta_sigma, stagnation_generations, patience, cma_options,
                                 restart_regimes, popsize_growth, scouts, scout_generations, scout_halving)
    search = dict(meta_episodes=meta_episodes, meta_sigma=meta_sigma, starts=starts, restart_from_best=restart_from_best,
                  stagnation_tol=stagnation_tol, max_attempt_generations=max_attempt_generations, small_share=small_share,
                  patience=patience, switch_distance=switch_distance, next_starts=next_starts, **settings)
    out = None if out_dir is None else Path(out_dir)
    details_path = None
    if out is not None:
        details_path = _open_run_folder(out, _run_record(problem, seed, sigma0, popsize, race_stall=race_stall, **search), problem)
    if optimizer is None:
        optimizer = make_optimizer(problem, seed, sigma0, popsize, race_stall=_race_stall(race_stall, popsize), **search)
    stop = _checked_stop_distance(stop_distance)
    n_episodes, logged = _resumed_budget(n_episodes, out, details_path, stop if stop_on_success else None, stall)
    t0 = time.perf_counter()
    callback = _generation_callback(problem, progress, stop_on_success, t0, stop, stall, logged)
    loop = run_search(optimizer, problem.batch_evaluator(executor, details_path), n_evaluations=n_episodes, out_dir=out, callback=callback)
    wall = time.perf_counter() - t0
    result = _result(problem, loop, wall)
    judged = -result.rewards[_race_start(loop.optimizer):]
    if stall is not None and result.stop_reason != "optimizer" and not result.reached(stop) and stall.stalled(judged):
        result.stop_reason = "stalled"
    return result


def _checked_stop_distance(stop_distance: float | None) -> float:
    """``refine``'s ``stop_distance`` (m; :data:`SUCCESS_DISTANCE` where None), within (0, SUCCESS_DISTANCE]."""
    stop = SUCCESS_DISTANCE if stop_distance is None else float(stop_distance)
    if not (np.isfinite(stop) and 0 < stop <= SUCCESS_DISTANCE):
        raise RefinementError(f"stop_distance must be within (0, {SUCCESS_DISTANCE}] m, got {stop_distance!r}")
    return stop


def _resumed_budget(n_episodes: int, out: Path | None, details_path: Path | None, stop: float | None,
                    stall: StallRule | AnyStall | None) -> tuple[int, list[float]]:
    """The budget of a run in ``out`` (a resumed run that had stopped at a success within ``stop``, or had stalled by
    ``stall`` in its current race, stays stopped) and the objectives its log already holds (for ``stall``)."""
    own = read_details(details_path) if details_path is not None else {}
    if stop is not None and any(stops_at(r, stop) for r in own.values()):
        n_episodes = min(n_episodes, len(own))
    logged = _logged_objectives(out) if stall is not None else []
    if stall is not None and stall.stalled(logged[_saved_race_start(out):]):
        n_episodes = min(n_episodes, len(logged))
    return n_episodes, logged


def race_stall_rule(episodes: int, tol: float = 0.01, after: int | None = None, beyond: float = SUCCESS_DISTANCE) -> StallRule:
    """The rule of ``refine(race_stall=)``: a race has stalled where its best gained less than ``tol`` (m) over its last
    ``episodes`` episodes, not before episode ``after`` of the race (default ``2 * episodes``), while the run is farther
    than ``beyond`` (m) from its target (``besdrake refine --race-stall-episodes``; session 44's benchmark: 200)."""
    return StallRule(episodes, tol, 2 * int(episodes) if after is None else after, beyond)


def _race_stall(rule: StallRule | None, popsize: int):
    """``refine``'s ``race_stall`` as the optimizer's :class:`~besdrake.search.cmaes.RaceStall` (episodes to
    generations of ``popsize``), None where not given."""
    from besdrake.search.cmaes import RaceStall

    if rule is None:
        return None
    generations = -(-int(rule.episodes) // int(popsize))
    return RaceStall(generations, float(rule.tol), -float(rule.beyond), -(-int(rule.after) // int(popsize)))


def _race_start(optimizer) -> int:
    """The episodes before ``optimizer``'s current race where it races on stalls (0 for any other optimizer)."""
    start = getattr(optimizer, "race_start_episode", None)
    return int(start()) if callable(start) else 0


def _saved_race_start(out: Path | None) -> int:
    """:func:`_race_start` of the optimizer saved in ``out`` (0 where there is none or it cannot be read: the loop
    reports a damaged state itself)."""
    from besdrake.search.loop import STATE_FILE, load_state

    if out is None or not (out / f"{STATE_FILE}.json").is_file():
        return 0
    try:
        state = load_state(out / STATE_FILE)["optimizer"]
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile):  # a damaged state is the loop's to report
        return 0
    has_rule = isinstance(state, dict) and state.get("config", {}).get("race_stall") is not None
    return int(state.get("halving", {}).get("race_episode", 0)) if has_rule else 0


def _saved_scout_generations(out: Path | None) -> int | None:
    """The rung length of the scouts' race that the run in ``out`` began with (its record), None where there is none."""
    path = None if out is None else out / PROBLEM_FILE
    if path is None or not path.is_file():
        return None
    try:
        value = json.loads(path.read_text()).get("scout_generations")
    except (OSError, json.JSONDecodeError, AttributeError):
        return None  # _open_run_folder reports a corrupt record
    return int(value) if isinstance(value, int) and value >= 1 else None


def _logged_objectives(out: Path | None) -> list[float]:
    """The objectives (minus the rewards; NaN where failed) of the episodes a resumed run's log already holds."""
    import csv

    from besdrake.search.loop import EPISODES_FILE

    path = None if out is None else out / EPISODES_FILE
    if path is None or not path.is_file():
        return []
    with path.open(newline="") as f:
        return [-float(r["reward"]) if r["failed"] == "0" else float("nan") for r in csv.DictReader(f)]


def _checked_settings(n_episodes: int, meta_episodes: int, meta_sigma: float, stagnation_generations: int | None,
                      patience: int, cma_options, restart_regimes, popsize_growth, scouts, scout_generations,
                      scout_halving) -> dict[str, Any]:
    """The search settings of :func:`refine` with the defaults filled in, checked (:class:`RefinementError`)."""
    if n_episodes < 1:
        raise RefinementError(f"n_episodes must be >= 1, got {n_episodes}")
    cma_options, stagnation_generations, restart_regimes, popsize_growth = _search_defaults(
        cma_options, stagnation_generations, meta_episodes, restart_regimes, popsize_growth)
    if stagnation_generations < 0:
        raise RefinementError(f"stagnation_generations must be >= 0, got {stagnation_generations}")
    if int(patience) != patience or patience < 1:
        raise RefinementError(f"patience must be an integer >= 1, got {patience!r}")
    scouts, scout_generations, scout_halving = _scouting_defaults(scouts, scout_generations, scout_halving)
    if meta_episodes < 0 or not (np.isfinite(meta_sigma) and meta_sigma > 0):
        raise RefinementError(f"meta_episodes must be >= 0 and meta_sigma > 0, got {meta_episodes}, {meta_sigma}")
    return dict(cma_options=cma_options, stagnation_generations=stagnation_generations, restart_regimes=restart_regimes,
                popsize_growth=popsize_growth, scouts=scouts, scout_generations=scout_generations, scout_halving=scout_halving)


def _run_record(problem: RefinementProblem, seed: int, sigma0: float, popsize: int, *, meta_episodes: int, meta_sigma: float,
                stagnation_generations: int, starts, restart_from_best: bool, stagnation_tol: float,
                max_attempt_generations: int, cma_options: dict[str, Any], popsize_growth: float, restart_regimes: str,
                small_share: float, patience: int, scouts: int, scout_generations: int, scout_halving: bool,
                switch_distance: float | None = None, next_starts=None, race_stall: StallRule | None = None) -> dict[str, Any]:
    """The run's ``problem.json``: the problem and every setting that differs from the plain search (what a resumed
    run must match)."""
    desc = problem.describe() | {"seed": int(seed), "sigma0": float(sigma0), "popsize": int(popsize)}
    if meta_episodes > 0:
        desc |= {"meta_episodes": int(meta_episodes), "meta_sigma": float(meta_sigma)}
    if stagnation_generations > 0:
        desc |= {"stagnation_generations": int(stagnation_generations), "stagnation_tol": float(stagnation_tol),
                 "max_attempt_generations": int(max_attempt_generations), "restart_from_best": bool(restart_from_best),
                 "starts": None if starts is None else np.atleast_2d(np.asarray(starts, dtype=float)).tolist()}
        if popsize_growth != 1.0:
            desc |= {"popsize_growth": float(popsize_growth)}
        if restart_regimes != "large":
            desc |= {"restart_regimes": str(restart_regimes)}
        if small_share != 1.0:
            desc |= {"small_share": float(small_share)}
        if restart_regimes == "local":
            desc |= {"patience": int(patience)}
        if scouts > 1:
            desc |= {"scouts": int(scouts), "scout_generations": int(scout_generations)}
            if scout_halving:
                desc["scout_halving"] = True
            if switch_distance is not None:
                desc["switch_distance"] = float(switch_distance)
            if next_starts is not None:
                desc["next_starts"] = np.atleast_2d(np.asarray(next_starts, dtype=float)).tolist()
            if race_stall is not None:
                desc["race_stall"] = {"episodes": int(race_stall.episodes), "tol": float(race_stall.tol),
                                      "after": int(race_stall.after), "beyond": float(race_stall.beyond)}
    if cma_options:
        desc |= {"cma_options": dict(cma_options)}
    return desc


def _open_run_folder(out: Path, desc: dict[str, Any], problem: RefinementProblem) -> Path:
    """Create ``out`` with the run's record, or check that it holds the same run (then load its episode records into
    ``problem``); the path of its details file."""
    out.mkdir(parents=True, exist_ok=True)
    desc_path = out / PROBLEM_FILE
    if desc_path.exists():
        try:
            old = json.loads(desc_path.read_text())
        except (OSError, json.JSONDecodeError) as err:
            raise RefinementError(f"{desc_path} is corrupt: {err}") from err
        if json.dumps(old, sort_keys=True) != json.dumps(json.loads(json.dumps(desc)), sort_keys=True):
            raise RefinementError(f"{out} holds another refinement run (different template, target, seed or settings); use another folder")
    else:
        write_json(desc_path, desc)
    details_path = out / DETAILS_FILE
    problem.records.update(read_details(details_path))
    return details_path


def stops_at(r, stop_distance: float = SUCCESS_DISTANCE) -> bool:
    """Whether episode record ``r`` ends a run that stops on success (:func:`refine`'s ``stop_distance``)."""
    if r is None or not r.success:
        return False
    return (r.robust_distance if np.isfinite(r.robust_distance) else r.distance) < stop_distance


def _generation_callback(problem: RefinementProblem, progress, stop_on_success: bool, t0: float, stop_distance: float = SUCCESS_DISTANCE,
                         stall: StallRule | AnyStall | None = None, objectives: list[float] | None = None):
    """The search loop's callback: reports ``progress`` after each generation and stops at a success when asked, or
    once the run has stalled (``stall``; ``objectives``: the episodes logged before a resume)."""
    best = [np.inf]
    last = [t0]
    history = list(objectives or [])

    def callback(info) -> bool:
        recs = [problem.records.get(params_key(x)) for x in info.candidates]
        for r in recs:
            if r is not None and np.isfinite(r.distance) and r.penalty == 0.0:
                best[0] = min(best[0], r.distance)
        now = time.perf_counter()
        if progress is not None:
            progress(info.n_evaluations, best[0], now - last[0])
        last[0] = now
        history.extend(np.where(info.failed, np.nan, -np.asarray(info.rewards, dtype=float)).tolist())
        if stop_on_success and any(stops_at(r, stop_distance) for r in recs):
            return True
        return bool(stall is not None and stall.stalled(history[_race_start(info.optimizer):]))

    return callback


def _result(problem: RefinementProblem, loop, wall: float) -> RefinementResult:
    recs = [problem.records.get(params_key(x)) for x in loop.params]
    distances = np.array([np.nan if r is None else r.distance for r in recs], dtype=float)
    successes = np.array([r is not None and r.success for r in recs], dtype=bool)
    penalties = np.array([np.nan if r is None else r.penalty for r in recs], dtype=float)
    rewards = np.asarray(loop.rewards, dtype=float)
    ok = np.flatnonzero(np.isfinite(rewards) & ~loop.failed)
    if successes.any():
        # best = the closest successful episode (with a robust check: the one of the highest, robust, reward)
        idx = np.flatnonzero(successes)
        i = int(idx[np.argmin(distances[idx])]) if problem.robust is None else int(idx[np.argmax(rewards[idx])])
    elif ok.size:
        i = int(ok[np.argmax(rewards[ok])])
    else:
        i = -1
    if i >= 0:
        r = recs[i]
        best_theta, best_dmp = problem.theta(loop.params[i]), problem.dmp(loop.params[i])
        best_reward, best_distance = float(rewards[i]), float(distances[i])
        best_td = None if r is None else r.touchdown
    else:
        best_theta, best_reward, best_distance, best_td = problem.scaling.theta0.copy(), -np.inf, np.inf, None
        best_dmp = problem.parameterization.from_vector(best_theta)
    first = int(np.argmax(successes)) + 1 if successes.any() else None
    robust = np.array([np.nan if r is None else r.robust_distance for r in recs], dtype=float)
    return RefinementResult(
        best_theta=best_theta, best_reward=best_reward, best_distance=best_distance, best_touchdown=best_td,
        success=bool(successes.any()), episodes_to_success=first, n_episodes=int(loop.n_evaluations),
        n_failed=int(loop.n_failed), wall_time=wall, rewards=rewards, distances=distances, successes=successes,
        penalties=penalties, resumed=bool(loop.resumed), stop_reason=loop.stop_reason,
        attempts=[dict(a) for a in getattr(loop.optimizer, "attempt_history", [])], robust_distances=robust,
        robust_rollouts=np.array([0 if r is None else r.robust_rollouts for r in recs], dtype=int), robust=problem.robust is not None,
        best_robust_distance=float(robust[i]) if i >= 0 else float("nan"), best_dmp=best_dmp,
    )


def plot_learning_curves(results: Sequence[RefinementResult], path: str | Path) -> Path:
    """PNG of the best target distance within limits over the episodes, one line per run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for k, r in enumerate(results):
        best = r.best_so_far()
        ax.plot(np.arange(1, best.size + 1), best, label=f"run {k}")
    ax.axhline(SUCCESS_DISTANCE, color="gray", lw=1, ls="--", label="goal 0.1 m")
    ax.set_xlabel("episode")
    ax.set_ylabel("best distance within limits so far (m)")
    ax.set_yscale("log")
    ax.legend()
    fig.tight_layout()
    path = Path(path)
    _save_figure(fig, path, dpi=100)
    plt.close(fig)
    return path
