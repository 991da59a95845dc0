"""The throwing task's learn stage 4, ``refine``: policy search in simulation (CMA-ES on the 49 DMP parameters) from
the imitated throws; its runs, starts, stall rule and robust check from the configuration's ``refinement`` section."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from besdrake.pipeline.learn import Context
from besdrake.pipeline.learn import stage_executor as _executor

if TYPE_CHECKING:
    from besdrake.search.refinement import StallRule


def refine_from(ctx: Context, dmps: list, scenario: str, out: Path, budget: int, tag: str, scouting: bool = True,
                target: tuple[float, float] | None = None, plans: int | None = None,
                reward_settings: dict[str, Any] | None = None, sigma0: float | None = None, start_group: int = 0,
                follow_through: float | None = None, robust: bool = True, far_stall: StallRule | None = None) -> dict[str, Any]:
    """CMA-ES from the best of ``dmps`` (the paper uses all available plans) in ``scenario``. The default search's scouts
    (short first attempts from the best throws) run only with ``scouting`` and where they take at most half of
    ``budget``: a re-refinement from throws refined already goes straight to CMA-ES from the best of them.
    ``target`` and ``plans`` (runs): the refinement section's unless given; ``reward_settings``: more settings of the
    task's reward (e.g. the template reach's ``radial``); ``sigma0``: CMA-ES's initial step (normalised units; None: the
    refinement's default); ``start_group``: the first run starts from the throws ranked ``4 * start_group`` on (later
    runs from the next groups where ``refinement.run_starts`` is diverse); ``follow_through``: s after each start throw's
    release from which its plans are slowed where they break a limit, as a template plays them (None: off); ``robust``:
    the refinement's robust check (``refinement.robust_sd``) where it is on (False: every throw scored as thrown);
    ``far_stall``: a :class:`~besdrake.search.refinement.StallRule` that ends a run as well as the refinement's own
    (e.g. one for runs that stall far from their goal; None: the refinement's only)."""
    from besdrake.search.refinement import (DEFAULT_SCOUTS, DEFAULT_SIGMA0, SUCCESS_DISTANCE, AnyStall, RefinementProblem, plot_learning_curves,
                                            rank_starts, refine, scouting_episodes)
    from besdrake.search.refinement.run import stops_at
    from besdrake.sim.scheduler import run_concurrently
    from besdrake.task import DEFAULT_TASK, get_task
    from besdrake.tasks.throwing.template_base import follow_through_phase

    cfg = ctx.config["refinement"]
    task = str(ctx.config.get("task") or DEFAULT_TASK)
    reward = get_task(task).reward(target=tuple(cfg["target"] if target is None else target), **(reward_settings or {}))
    n_runs = int(cfg["plans"] if plans is None else plans)
    robot = ctx.robot(scenario)
    settings = refinement_settings(ctx.config)
    check = _robust_check(task, scenario, settings) if robust else None
    with _executor(ctx, scenario) as executor:
        phases = [follow_through_phase(d, executor, robot, follow_through) for d in dmps]
        problems = [RefinementProblem(robot, d, reward, task=task, robust=check, follow_through=ph) for d, ph in zip(dmps, phases)]
        ranking = rank_starts(problems, executor)
        index, start = ranking[0]
        problem = problems[index]
        records = dict(ranking)
        if settings["stop_on_success"] and stops_at(start, settings["stop_distance"] or SUCCESS_DISTANCE):
            return _keep_start(ctx, problem, robot, index, start, out, tag)
        scouts = DEFAULT_SCOUTS if scouting and 2 * scouting_episodes(int(cfg["population"])) <= int(budget) else 0
        diverse = bool(scouts) and settings["run_starts"] == "diverse"
        run_starts = [_run_starts(problems, ranking, start_group + (k if diverse else 0), bool(scouts)) for k in range(n_runs)]

        def run_job(k: int):
            """CMA-ES run ``k`` (its own seed, start throws and resumable folder) on the shared executor ``ex``."""
            def job(ex):
                i, starts = run_starts[k].index, run_starts[k].starts
                ctx.progress(f"{tag}: CMA-ES run {k + 1}/{n_runs} from throw {i} ({records[i].distance:.2f} m from the target)")
                return refine(run_starts[k].problem, ex, n_episodes=int(budget), seed=int(cfg["seed"]) + k, out_dir=out / f"run{k}",
                              sigma0=DEFAULT_SIGMA0 if sigma0 is None else sigma0,
                              popsize=int(cfg["population"]), stop_on_success=settings["stop_on_success"],
                              stop_distance=settings["stop_distance"], starts=starts, scouts=scouts,
                              stall=AnyStall.of(settings["stall"], far_stall),
                              switch_distance=settings["switch_distance"] if scouts else None)
            return job

        jobs = [run_job(k) for k in range(n_runs)]
        if settings["stop_on_success"] and settings["runs_in_turn"]:
            results = _runs_in_turn(jobs, executor, settings["turn_distance"] or settings["stop_distance"] or SUCCESS_DISTANCE)
        else:  # independent runs: their generations share the pool, one wider batch per round (same results)
            results = run_concurrently(executor, jobs)
    runs = _save_refined(robot, results, out)
    for k, run in enumerate(runs):
        run["start_throw"] = int(run_starts[k].index)
    plot_learning_curves(results, out / "learning_curve.png")
    # The best run is judged by throws within every joint limit: a closer throw that breaks a limit is no plan.
    best = min(runs, key=lambda r: r["best_distance_within_limits_m"] if r["best_distance_within_limits_m"] is not None else np.inf)
    return {
        "start_throw": int(index),
        "start_distance_m": start.distance,
        "runs": runs,
        "success_runs": sum(bool(r["success"]) for r in runs),
        "median_episodes_to_success": float(np.median([r["episodes_to_success"] for r in runs if r["episodes_to_success"]])) if any(r["episodes_to_success"] for r in runs) else None,
        "best_distance_within_limits_m": best["best_distance_within_limits_m"],
        "best_dmp": best["dmp"],
    }


def _runs_in_turn(jobs: list, executor, turn_distance: float) -> list:
    """The CMA-ES runs one after the other on ``executor``, up to the first that found a throw within
    ``turn_distance`` (its robust distance where checked): a later run only where every earlier one failed."""
    results = []
    for job in jobs:
        results.append(job(executor))
        if results[-1].reached(turn_distance):
            break
    return results


def _keep_start(ctx: Context, problem, robot, index: int, start, out: Path, tag: str) -> dict[str, Any]:
    """No CMA-ES run: the best start throw already lands within the stop distance (e.g. a re-refinement from a refined
    throw); it is kept as ``refined0`` (0 episodes)."""
    ctx.progress(f"{tag}: throw {index} lands {start.distance:.3f} m from the target already: kept, no CMA-ES run")
    out.mkdir(parents=True, exist_ok=True)
    _save_throw(problem.parameterization.from_vector(problem.theta(np.zeros(problem.n_params))), robot, out, 0)  # retimed, as evaluated
    run = {"success": True, "episodes_to_success": 0, "best_distance_m": start.distance, "best_distance_within_limits_m": start.distance,
           "best_touchdown_m": list(start.touchdown), "n_episodes": 0, "stop_reason": "start", "dmp": "refined0.dmp.json"}
    if np.isfinite(start.robust_distance):
        run["best_robust_distance_m"] = start.robust_distance
    return {"start_throw": int(index), "start_distance_m": start.distance, "runs": [run], "success_runs": 1,
            "median_episodes_to_success": 0.0, "best_distance_within_limits_m": start.distance, "best_dmp": run["dmp"]}


def _run_starts(problems: list, ranking: list, group: int, scouting: bool = True):
    """:func:`~besdrake.search.refinement.family_run` over the throws of ``ranking`` that could be simulated: the run's
    start throw, its problem and its scouts' start points (each imitated throw itself); without ``scouting`` the start
    throw's own problem (its restarts begin at the best throw so far)."""
    from besdrake.search.refinement import family_run, hybrid_run, simulated_order

    return (family_run if scouting else hybrid_run)(problems, simulated_order(ranking), group)


def _save_refined(robot, results: list, out: Path) -> list[dict[str, Any]]:
    """Each run's best throw (its own DMP: that of the imitated throw it varies) as ``refinedK.dmp.json`` and
    ``refinedK.plan.json``; the runs' summaries."""
    runs = []
    for k, result in enumerate(results):
        _save_throw(result.best_dmp, robot, out, k)
        runs.append(result.summary() | {"dmp": f"refined{k}.dmp.json"})
    return runs


def _save_throw(dmp, robot, out: Path, k: int) -> None:
    """A refined throw as ``refinedK.dmp.json`` and its motion plan (10 ms samples) as ``refinedK.plan.json``."""
    from besdrake.imitation import DMPParameterization

    dmp.save(out / f"refined{k}.dmp.json")
    DMPParameterization(dmp, robot.joint_names).motion_plan(DMPParameterization(dmp).to_vector(), dt=0.01).save(out / f"refined{k}.plan.json")


def refinement_settings(config: dict[str, Any]) -> dict[str, Any]:
    """The refinement section's stop and robustness settings, checked (:class:`~besdrake.pipeline.config.ConfigError`):
    ``stop_on_success``, ``runs_in_turn`` (the runs one after the other up to the first success), ``stop_distance`` (m;
    null: the success distance), ``turn_distance`` (m: with ``runs_in_turn`` a run follows only where every earlier one
    ended beyond it; null: the stop distance) and ``robust_sd`` (m per axis; 0: no robust check), ``robust_radius`` (m),
    ``robust_frontier`` (m; null or absent, as in a run folder of before: every throw within the radius checked, not only
    those that could become the run's best), ``stall`` (a
    :class:`~besdrake.search.refinement.StallRule` from ``stall_episodes`` / ``stall_tol`` / ``stall_after``; None where
    ``stall_episodes`` is null), ``switch_distance`` (m; a raced scout that stalls farther hands over to the next one;
    null: never)."""
    from besdrake.pipeline.config import ConfigError
    from besdrake.search.refinement import SUCCESS_DISTANCE, RefinementError
    from besdrake.search.refinement.optimizer import checked_switch_distance
    from besdrake.search.refinement.robust import ROBUST_RADIUS

    cfg = config["refinement"]
    try:
        stop = cfg.get("stop_distance")
        out = {"stop_on_success": bool(cfg.get("stop_on_success", True)), "stop_distance": None if stop is None else float(stop),
               "runs_in_turn": bool(cfg.get("runs_in_turn", False)), "run_starts": str(cfg.get("run_starts", "same")),
               "robust_sd": float(cfg.get("robust_sd", 0.0)), "robust_radius": float(cfg.get("robust_radius", ROBUST_RADIUS)),
               "robust_frontier": None if cfg.get("robust_frontier") is None else float(cfg["robust_frontier"])}
        out["switch_distance"] = checked_switch_distance(cfg.get("switch_distance"))
    except (TypeError, ValueError, RefinementError) as err:
        raise ConfigError(f"refinement: {err}") from None
    out["stall"] = _stall_rule(cfg)
    out["turn_distance"] = _turn_distance(cfg.get("turn_distance"))
    if out["stop_distance"] is not None and not (0 < out["stop_distance"] <= SUCCESS_DISTANCE):
        raise ConfigError(f"refinement: stop_distance must be within (0, {SUCCESS_DISTANCE}] m or null, got {stop!r}")
    if out["run_starts"] not in ("same", "diverse"):
        raise ConfigError(f"refinement: run_starts must be 'same' or 'diverse', got {out['run_starts']!r}")
    if not (0 <= out["robust_sd"] <= 0.005) or not (out["robust_radius"] > 0):
        raise ConfigError(f"refinement: robust_sd must be within 0..0.005 m and robust_radius > 0 m, "
                          f"got {out['robust_sd']!r}, {out['robust_radius']!r}")
    if out["robust_frontier"] is not None and not (0 < out["robust_frontier"] < out["robust_radius"]):
        raise ConfigError(f"refinement: robust_frontier must be within (0, robust_radius) m or null, got {out['robust_frontier']!r}")
    return out


def _turn_distance(value: Any) -> float | None:
    """``refinement.turn_distance`` checked: None, or a distance within (0, the success distance] m."""
    from besdrake.pipeline.config import ConfigError
    from besdrake.search.refinement import SUCCESS_DISTANCE

    try:
        turn = None if value is None else float(value)
    except (TypeError, ValueError):
        turn = float("nan")
    if turn is not None and not (0 < turn <= SUCCESS_DISTANCE):
        raise ConfigError(f"refinement: turn_distance must be within (0, {SUCCESS_DISTANCE}] m or null, got {value!r}")
    return turn


def _stall_rule(cfg: dict[str, Any]):
    """The refinement section's stall rule (None: ``stall_episodes`` null or absent)."""
    from besdrake.pipeline.config import ConfigError
    from besdrake.search.refinement import RefinementError, StallRule

    if cfg.get("stall_episodes") is None:
        return None
    try:
        return StallRule(int(cfg["stall_episodes"]), float(cfg.get("stall_tol", 0.01)), int(cfg.get("stall_after", 400)))
    except (TypeError, ValueError, RefinementError) as err:
        raise ConfigError(f"refinement: {err}") from None


def _robust_check(task: str, scenario: str, settings: dict[str, Any]):
    """The refinement's :class:`~besdrake.search.refinement.robust.RobustCheck` over the task's setup scatter in
    ``scenario`` (None with ``robust_sd`` 0)."""
    from besdrake.search.refinement.robust import RobustCheck
    from besdrake.sim.scenario import load_scenario
    from besdrake.task import get_task

    if settings["robust_sd"] <= 0:
        return None
    return RobustCheck.from_task(get_task(task), load_scenario(scenario), settings["robust_sd"], radius=settings["robust_radius"],
                                 frontier=settings.get("robust_frontier"))


def stage_refine(ctx: Context, out: Path) -> dict[str, Any]:
    return refine_from(ctx, imitated_dmps(ctx), ctx.config["scenario"], out, int(ctx.config["refinement"]["evaluations"]), "refine")


def imitated_dmps(ctx: Context) -> list:
    """The imitation stage's DMPs (RuntimeError where it produced none)."""
    from besdrake.imitation import load_dmp

    files = sorted((ctx.run.root / "03_imitate").glob("*.dmp.json"))
    if not files:
        raise RuntimeError("no imitated throw to refine (the imitation stage produced no plan)")
    return [load_dmp(f) for f in files]
