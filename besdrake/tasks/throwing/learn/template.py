"""The throwing task's learn stages 8 and 9: ``template`` (behaviour template learning over the target position, from
the refined throw or a base refined further for reach, kept by the floor rule) and ``pool`` (the template pool)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np

from besdrake._io import save_figure as _save_figure
from besdrake.pipeline.learn import Context
from besdrake.pipeline.learn import stage_executor as _executor
from besdrake.tasks.throwing.learn.refinement import imitated_dmps, refine_from, refinement_settings
from besdrake.tasks.throwing.learn.transfer import lab_of, open_log, refined_scenario


def _best_throw(ctx: Context) -> Path:
    for candidate in (ctx.run.root / "07_transfer_refined" / "best.dmp.json", ctx.run.root / "05_transfer" / "best.dmp.json"):
        if candidate.is_file():
            return candidate
    return ctx.run.root / "04_refine" / ctx.run.done(4, "refine")["summary"]["best_dmp"]


#: What the template's reach refinement scores: "point" the touchdown's distance to ``reach_target``, "range" its
#: distance from the robot against the target's (any direction: the template's joint-1 goal turns the throw).
REACH_OBJECTIVES = ("point", "range")


#: The far stall rule of a reach refinement from a refined throw (``templates.reach_stall_beyond``, m): after
#: REACH_FAR_STALL_AFTER episodes, a run whose best is still farther than that from the reach target and gained less than
#: REACH_FAR_STALL_TOL over its last REACH_FAR_STALL_EPISODES episodes ends (the refinement's own rule still holds). A
#: family that falls short of the target plateaus within about 50 episodes. Session 42, the 29 distinct reach refinements
#: from refined throws in sessions 35-42's learn runs, replayed: 100 / 1 cm / 150 beyond 0.25 m stops 4 (16 % of their
#: episodes saved; they ended 0.28-0.40 m off), none of the 18 that reach 0.1 m of the target loses it; after 100
#: episodes, or with 2 cm, one is lost (REFINEMENT.md).
REACH_FAR_STALL_EPISODES = 100
REACH_FAR_STALL_TOL = 0.01
REACH_FAR_STALL_AFTER = 150

#: The reach floor (m, the test contexts' mean miss no meta-parameters avoid) at which the template stage stops looking
#: for a base in other imitated throws (``templates.reach_floor_goal``). Derived from issue 27's lab target, not fitted:
#: the default lab scatters a touchdown by SD 5 cm per axis, so a plan that misses by m in simulation measures on average
#: the Rice mean 5 sqrt(pi/2) L_1/2(-m^2 / 50) cm there: 6.27 cm for m = 0, 6.82 cm for 3 cm, 7.01 cm for 3.5 cm. A base
#: whose floor is within 3 cm leaves a template that can meet 7 cm in the lab with a margin for what 80 episodes miss.
REACH_FLOOR_GOAL = 0.03


def template_reach_settings(config: dict[str, Any]) -> dict[str, Any]:
    """The templates section's reach settings, checked (:class:`~besdrake.pipeline.config.ConfigError`): the reach
    refinement's ``target`` (m, or None: off), ``evaluations`` (episodes), ``objective`` (:data:`REACH_OBJECTIVES`) and
    ``sigma`` (its CMA-ES's initial step), ``far_stall`` (the far stall rule of the reach refinements from refined
    throws, :data:`REACH_FAR_STALL_EPISODES`, or None), ``robust`` (whether it scores throws by the refinement's robust
    check), ``extend_probes`` (the template's probes beyond its slowest time), ``slowest`` (the template's slowest
    execution time, x its base's), ``robust_sd`` (m: the setup scatter the template's episodes are rewarded over; 0: none),
    ``other_evaluations``, ``other_groups`` and ``floor_goal`` (the search in other imitated throws, :func:`_other_families`)."""
    from besdrake.pipeline.config import ConfigError
    from besdrake.search.templates import EXTEND_PROBES, SCALE_SLOWEST
    from besdrake.search.refinement import DEFAULT_SIGMA0, StallRule

    cfg = config["templates"]
    target, budget, objective = cfg.get("reach_target"), cfg.get("reach_evaluations", 0), cfg.get("reach_objective", "point")
    try:
        target = None if target is None else tuple(float(v) for v in target)
        budget = int(budget)
        other = int(cfg.get("reach_other_evaluations", 0))
        other_groups = int(cfg.get("reach_other_groups", 1))
        floor_goal = float(cfg.get("reach_floor_goal", REACH_FLOOR_GOAL))
        other_runs = cfg.get("reach_other_runs", False)
        beyond = cfg.get("reach_stall_beyond")
        beyond = None if beyond is None else float(beyond)
        sigma = float(cfg.get("reach_sigma", DEFAULT_SIGMA0))
        extend = int(cfg.get("extend_probes", EXTEND_PROBES))
        slowest = float(cfg.get("slowest", SCALE_SLOWEST))
        follow = cfg.get("follow_through")
        follow = None if follow is None else float(follow)
        robust = cfg.get("reach_robust", True)
        robust_sd = float(cfg.get("robust_sd", 0.0))
    except (TypeError, ValueError) as err:
        raise ConfigError(f"templates: reach_target must be [x, y] in m or null, reach_evaluations an integer and slowest, "
                          f"reach_stall_beyond and the other reach settings numbers ({err})") from None
    if target is not None and (len(target) != 2 or not np.isfinite(target).all()) or budget < 0:
        raise ConfigError(f"templates: reach_target must be two finite numbers (m) or null and reach_evaluations >= 0, "
                          f"got {cfg.get('reach_target')!r}, {cfg.get('reach_evaluations')!r}")
    if other < 0:
        raise ConfigError(f"templates: reach_other_evaluations must be >= 0, got {cfg.get('reach_other_evaluations')!r}")
    if not (np.isfinite(floor_goal) and 0.0 <= floor_goal <= 0.5):
        raise ConfigError(f"templates: reach_floor_goal must be within [0, 0.5] m, got {cfg.get('reach_floor_goal')!r}")
    if not 1 <= other_groups <= 5:
        raise ConfigError(f"templates: reach_other_groups must be an integer within [1, 5], got {cfg.get('reach_other_groups')!r}")
    if beyond is not None and not (np.isfinite(beyond) and 0.0 <= beyond <= 2.0):
        raise ConfigError(f"templates: reach_stall_beyond must be within [0, 2] m or null, got {cfg.get('reach_stall_beyond')!r}")
    if not 0 <= extend <= 10:
        raise ConfigError(f"templates: extend_probes must be an integer within [0, 10], got {cfg.get('extend_probes')!r}")
    if not (np.isfinite(sigma) and 0.0 < sigma <= 5.0):
        raise ConfigError(f"templates: reach_sigma must be within (0, 5] (CMA-ES's initial step), got {cfg.get('reach_sigma')!r}")
    if objective not in REACH_OBJECTIVES:
        raise ConfigError(f"templates: reach_objective must be one of {REACH_OBJECTIVES}, got {objective!r}")
    if not (1.0 < slowest <= 10.0):
        raise ConfigError(f"templates: slowest must be within (1, 10] (x the base's execution time), got {cfg.get('slowest')!r}")
    if not (np.isfinite(robust_sd) and 0.0 <= robust_sd <= 0.05):
        raise ConfigError(f"templates: robust_sd must be within [0, 0.05] m (0: off), got {cfg.get('robust_sd')!r}")
    if not isinstance(robust, bool):
        raise ConfigError(f"templates: reach_robust must be true or false, got {robust!r}")
    if not isinstance(other_runs, bool):
        raise ConfigError(f"templates: reach_other_runs must be true or false, got {other_runs!r}")
    if follow is not None and not (np.isfinite(follow) and 0.0 <= follow <= 1.0):
        raise ConfigError(f"templates: follow_through must be a time within [0, 1] s after the release, or null, got {cfg.get('follow_through')!r}")
    return {"target": target if budget > 0 else None, "evaluations": budget, "slowest": slowest, "objective": objective,
            "sigma": sigma, "extend_probes": extend, "other_evaluations": other, "other_groups": other_groups, "floor_goal": floor_goal,
            "other_runs": other_runs,
            "far_stall": None if beyond is None else StallRule(REACH_FAR_STALL_EPISODES, REACH_FAR_STALL_TOL, REACH_FAR_STALL_AFTER, beyond),
            "follow_through": follow, "robust": robust, "robust_sd": robust_sd}


def _template_base(ctx: Context, scenario: str, out: Path) -> tuple[Path, dict[str, Any]]:
    """The template's base: the best refined throw, refined further towards ``templates.reach_target`` (issue 27).

    A throw refined to land at the refinement's target drives a joint at its speed limit, so a template cannot make it
    throw farther: contexts beyond its touchdown are missed by the shortfall, while a slower execution reaches the nearer
    ones. Refined towards the farthest context, the base covers the context range. The further-refined throw is kept
    only where the template's reach probes of both throws leave it the smaller floor (the test contexts' mean distance
    that no meta-parameters avoid, :func:`~besdrake.search.templates.reach_floor`): a throw family may not reach the
    target, and one that lands a little farther may turn less far (joint 1's limits). Where that refinement ends short
    of the goal (0.1 m), more reach refinements look in other throw families: from each other refinement run's throw
    of another family (:func:`_other_runs_reach`, ``templates.reach_other_runs``) and, where no base so far leaves a
    floor within ``templates.reach_floor_goal``, from the imitated throws of the start groups after the refinement
    runs' (:func:`_other_families`, ``templates.reach_other_evaluations``, ``templates.reach_other_groups``); the floor
    rule picks among all the bases."""
    from besdrake.imitation import load_dmp

    base_file = _best_throw(ctx)
    settings = template_reach_settings(ctx.config)
    if settings["target"] is None:
        return base_file, {}
    result = _reach_refinement(ctx, [load_dmp(base_file)], scenario, out, settings["evaluations"], settings, "template reach")
    record = {"target_m": list(settings["target"]), "objective": settings["objective"]} | _reach_summary(result)
    if result["runs"][0].get("stop_reason") == "start" or result["best_distance_within_limits_m"] is None:
        return base_file, record | {"kept": False}
    candidates, kinds = [base_file, out / result["best_dmp"]], ["refined throw", "reach refinement"]
    for name, run in _other_runs_reach(ctx, base_file, scenario, out, settings, result["best_distance_within_limits_m"]):
        record.setdefault("other_runs", []).append({"from": name} | {k: run[k] for k in ("start_distance_m", "best_distance_m", "episodes")})
        candidates.append(run["best_file"])
        kinds.append(f"reach refinement from {name}")
    floors = _floors(ctx, scenario, candidates, settings)
    for other in _other_families(ctx, scenario, out, settings, min(floors), lambda f: _floors(ctx, scenario, [f], settings)[0]):
        keys = ("start_distance_m", "best_distance_m", "episodes", "start_group")
        record.setdefault("other_families", []).append({k: other[k] for k in keys})
        candidates.append(other["best_file"])
        kinds.append(f"other throws (start group {other['start_group']})")
        floors.append(other["floor_m"])
    pick = int(np.argmin(floors))
    record |= {"floor_m": floors, "kept": pick > 0, "kept_from": kinds[pick]}
    return candidates[pick], record


def _floors(ctx: Context, scenario: str, files: list[Path], settings: dict[str, Any]) -> list[float]:
    """Each base's reach floor (m: the test contexts' mean miss that no meta-parameters avoid,
    :func:`~besdrake.search.templates.reach_floor`), probed as the template will play it."""
    from besdrake.imitation import load_dmp
    from besdrake.search.templates import reach_floor
    from besdrake.tasks.throwing.template_base import follow_through_phase

    with _executor(ctx, scenario) as executor:
        robot = ctx.robot(scenario)
        dmps = [load_dmp(f) for f in files]
        return [reach_floor(d, executor, robot, slowest=settings["slowest"],
                            follow_through=follow_through_phase(d, executor, robot, settings["follow_through"])) for d in dmps]


def _reach_refinement(ctx: Context, dmps: list, scenario: str, out: Path, budget: int, settings: dict[str, Any], tag: str,
                      start_group: int = 0) -> dict[str, Any]:
    """One CMA-ES run towards the template's reach target; from a later start group (other imitated throws) with scouts
    where the budget allows them, from the refined throw without, and then also ended by the far stall rule
    (``templates.reach_stall_beyond``); its throws played as the template will play them (``templates.follow_through``),
    scored robustly only with ``templates.reach_robust``."""
    return refine_from(ctx, dmps, scenario, out, budget, tag, scouting=start_group > 0, target=settings["target"], plans=1,
                        reward_settings={"radial": True} if settings["objective"] == "range" else None, sigma0=settings["sigma"],
                        start_group=start_group, follow_through=settings["follow_through"], robust=settings["robust"],
                        far_stall=settings["far_stall"] if start_group == 0 else None)


def _other_run_throws(ctx: Context, base_file: Path, scenario: str) -> list[Path]:
    """The refinement runs' throws of another throw family than ``base_file`` (refined from another imitated throw: the
    base's search space does not represent them), in run order."""
    from besdrake.imitation import load_dmp, shared_parameterization

    files = sorted((ctx.run.root / "04_refine").glob("refined*.dmp.json"))
    if not files:
        return []
    _, kept = shared_parameterization([load_dmp(base_file)] + [load_dmp(f) for f in files], ctx.robot(scenario).joint_names)
    return [f for i, f in enumerate(files, start=1) if i not in kept]


def _other_runs_reach(ctx: Context, base_file: Path, scenario: str, out: Path, settings: dict[str, Any],
                      reached: float) -> list[tuple[str, dict[str, Any]]]:
    """Where the reach refinement ended ``reached`` m from its target, beyond the goal: one reach refinement (the same
    budget) from each of the refinement's other runs' throws of another family (``templates.reach_other_runs``). The
    refinement keeps the closest of its runs, but a throw family that lands on the refinement's target may reach no
    farther, while another run's lands a little off and reaches the far contexts (issue 27). Returns (throw file name,
    {start_distance_m, best_distance_m, episodes, best_file}) per run that ended within the joint limits."""
    from besdrake.imitation import load_dmp
    from besdrake.search.refinement import SUCCESS_DISTANCE

    if reached <= SUCCESS_DISTANCE or not settings["other_runs"]:
        return []
    found = []
    for f in _other_run_throws(ctx, base_file, scenario):
        name = f.name.split(".")[0]
        result = _reach_refinement(ctx, [load_dmp(f)], scenario, out / name, settings["evaluations"], settings,
                                   f"template reach (from {f.name})")
        if result["best_distance_within_limits_m"] is not None:
            found.append((f.name, _reach_summary(result) | {"best_file": out / name / result["best_dmp"]}))
    return found


def _reach_summary(result: dict[str, Any]) -> dict[str, Any]:
    """A reach refinement's start and best distance (m) and its episodes, as the template stage records them."""
    return {"start_distance_m": result["start_distance_m"], "best_distance_m": result["best_distance_within_limits_m"],
            "episodes": int(sum(r.get("n_episodes", 0) for r in result["runs"]))}


def _other_families(ctx: Context, scenario: str, out: Path, settings: dict[str, Any], floor: float,
                    floor_of: Callable[[Path], float]) -> list[dict[str, Any]]:
    """Where no base so far leaves a reach floor within ``floor_goal`` (the smallest ``floor`` m;
    ``templates.reach_floor_goal``): reach refinements from the imitated throws of the start groups after the
    refinement's runs' (:func:`_unsearched_group`; their scouts start from them: other throw families than the refined
    throws'), one group after another up to the first whose base's floor (``floor_of`` its file) is within the goal,
    ``other_groups`` at most (``templates.reach_other_groups``; never a group twice); none where ``other_evaluations``
    is 0. Each as its summary with ``start_group``, ``best_file`` (the first in ``out / "other"``, a later group g in
    ``out / "other_g"``) and ``floor_m``."""
    from besdrake.search.refinement import DEFAULT_SCOUT_STARTS

    found: list[dict[str, Any]] = []
    if floor <= settings["floor_goal"] or settings["other_evaluations"] <= 0:
        return found
    dmps = imitated_dmps(ctx)
    first = _unsearched_group(ctx)
    n_groups = -(-len(dmps) // DEFAULT_SCOUT_STARTS)  # a start group is a run's scouts' start throws
    for group in range(first, min(first + settings["other_groups"], n_groups)):
        where = out / ("other" if group == first else f"other_{group}")
        result = _reach_refinement(ctx, dmps, scenario, where, settings["other_evaluations"], settings,
                                   f"template reach (other throws, start group {group})", start_group=group)
        found.append(_reach_summary(result) | {"start_group": group, "best_file": where / result["best_dmp"]})
        found[-1]["floor_m"] = floor_of(found[-1]["best_file"])
        if found[-1]["floor_m"] <= settings["floor_goal"]:
            break
    return found


def _unsearched_group(ctx: Context) -> int:
    """The start group (imitated throws 4k+1 to 4k+4 by distance to the target) after those the refinement's runs
    started from: with ``refinement.run_starts`` diverse run k started from group k, so the group after the last run,
    otherwise group 1. The reach refinement ranks the throws towards its own target, so its groups are mostly, not
    exactly, the refinement's."""
    runs = ctx.run.done(4, "refine")["summary"].get("runs", [])
    return max(len(runs), 1) if refinement_settings(ctx.config)["run_starts"] == "diverse" else 1


def stage_template(ctx: Context, out: Path) -> dict[str, Any]:
    """BO-CPS over (execution time, joint-1 goal) in the refined simulation, from the refined throw refined further to
    reach the farthest context (:func:`_template_base`); tested in simulation and in the lab."""
    from besdrake.imitation import load_dmp
    from besdrake.search.templates import TEST_CONTEXTS, evaluate_template, train_template
    from besdrake.task import scenario_scatter
    from besdrake.tasks.throwing.template_base import follow_through_phase

    cfg = ctx.config["templates"]
    reach_settings = template_reach_settings(ctx.config)
    method = {"entropy_search": "es", "ucb": "ucb"}.get(cfg["acquisition"], cfg["acquisition"])
    scenario = refined_scenario(ctx)
    base_file, reach = _template_base(ctx, scenario, out / "reach")
    with _executor(ctx, scenario) as executor:
        base = load_dmp(base_file)
        follow = follow_through_phase(base, executor, ctx.robot(scenario), reach_settings["follow_through"])
        training = train_template(
            base, executor, method=method, n_episodes=int(cfg["episodes"]), seed=int(cfg["seed"]),
            name="throw", out_dir=out / "training", slowest=reach_settings["slowest"], extend_probes=reach_settings["extend_probes"],
            follow_through=follow, scatter=scenario_scatter(executor.scenario, reach_settings["robust_sd"]),
            provenance={"base": str(base_file), "scenario": scenario, "lab": ctx.config["lab"], "demonstrations": ctx.config["demonstrations"]},
        )
        sim_eval = evaluate_template(training.template, executor)
    training.template.save(out)
    lab = lab_of(ctx)
    log = open_log(out / "lab_log", lab)
    from besdrake.transfer.log import run_plans

    run_plans(lab, [training.template.instantiate(s) for s in TEST_CONTEXTS], log)
    lab_td = np.array([m.touchdown if m.touchdown is not None else [np.nan, np.nan] for m in log.measurements()])
    lab_dist = np.linalg.norm(lab_td - TEST_CONTEXTS, axis=1)
    _plot_template(TEST_CONTEXTS, sim_eval.touchdowns, lab_td, out / "template_accuracy.png")
    prov = training.template.provenance
    return {
        "method": method,
        "episodes": int(cfg["episodes"]),
        "probe_rollouts": int(prov["n_probe_rollouts"]),
        "base": str(base_file),
        "reach_refinement": reach,
        "follow_through": follow,
        "scenario": scenario,
        "meta_bounds": training.template.meta_bounds.tolist(),
        "base_reach_m": _base_reach(prov.get("reach_probe")),
        "model_floor_mean_m": _model_floor(training.template),
        "sim_mean_distance_m": float(sim_eval.mean_distance),
        "sim_distances_m": [round(float(d), 5) for d in sim_eval.distances],  # per test context (TEST_CONTEXTS' order)
        "lab_mean_distance_m": float(np.nanmean(lab_dist)),
        "lab_not_measured": int(np.isnan(lab_dist).sum()),
        # what the lab adds to the simulation's touchdowns (its own scatter and what the refined scenario misses)
        "lab_about_sim_mean_m": _nanmean_or_none(np.linalg.norm(lab_td - sim_eval.touchdowns, axis=1)),
        "training_wall_time_s": training.wall_time,
    }


def _nanmean_or_none(x: np.ndarray) -> float | None:
    return float(np.nanmean(x)) if np.isfinite(x).any() else None


def _base_reach(probe: dict | None) -> list[float] | None:
    """Nearest and farthest touchdown (m) of the template's probes of its base within the joint limits."""
    if not probe:
        return None
    r = np.linalg.norm(np.array(probe["touchdowns"], dtype=float), axis=1)[np.array(probe["within_limits"], dtype=bool)]
    r = r[np.isfinite(r)]
    return [float(r.min()), float(r.max())] if r.size else None


def _model_floor(template) -> float | None:
    """Mean distance (m) over the test contexts that the probes' model says no meta-parameters in the box avoid."""
    from besdrake.search.template_reach import ReachProbe, model_floor
    from besdrake.search.templates import TEST_CONTEXTS

    probe = template.provenance.get("reach_probe")
    if not probe:
        return None
    return float(np.mean(model_floor(ReachProbe.from_dict(probe), template.meta_bounds, TEST_CONTEXTS)))


def _plot_template(contexts: np.ndarray, sim_td: np.ndarray, lab_td: np.ndarray, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 6))
    ax.plot(contexts[:, 1], contexts[:, 0], "k+", ms=12, label="test targets")
    ax.plot(sim_td[:, 1], sim_td[:, 0], "o", mfc="none", label="simulation (refined)")
    ax.plot(lab_td[:, 1], lab_td[:, 0], "x", label="lab")
    for c, t in zip(contexts, lab_td):
        ax.plot([c[1], t[1]], [c[0], t[0]], "-", lw=0.5, color="grey")
    ax.set_xlabel("y (lateral, m)")
    ax.set_ylabel("x (forward, m)")
    ax.set_aspect("equal")
    ax.legend(fontsize=8)
    ax.set_title("behaviour template on the 16 test contexts")
    fig.tight_layout()
    _save_figure(fig, path, dpi=90)
    plt.close(fig)


def stage_pool(ctx: Context, out: Path) -> dict[str, Any]:
    from besdrake.search.templates import BehaviorTemplate, TemplatePool

    template = BehaviorTemplate.load(next((ctx.run.root / "08_template").glob("*.template.json")))
    pool = TemplatePool(out)
    pool.add(template, overwrite=True)
    return {"pool": str(out), "templates": pool.names(), "instantiate": f"besdrake template instantiate --pool {out} --name {template.name} --context X Y"}
