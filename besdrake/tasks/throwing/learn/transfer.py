"""The throwing task's learn stages 5 to 7: ``transfer`` (Transferability Approach with the designed simulation and the
lab), ``diagnose`` (what the simulation gets wrong, its cause, a refined scenario) and ``transfer_refined`` (the
Transferability Approach again, with the refined simulation)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from besdrake._io import write_json
from besdrake.pipeline.learn import Context, learn_scenario
from besdrake.pipeline.learn import stage_executor as _executor
from besdrake.tasks.throwing.learn.refinement import refine_from


def lab_of(ctx: Context):
    """The run's lab behind its safety gate (opened once per run and recorded among its inputs)."""
    from besdrake.transfer.lab import SafetyGate
    from besdrake.transfer.lab_config import open_lab, resolve_lab_path

    if "lab" not in ctx.cache:
        ctx.run.record_inputs({"lab": resolve_lab_path(ctx.config["lab"])})
        ctx.cache["lab"] = SafetyGate(open_lab(ctx.config["lab"]))
    return ctx.cache["lab"]


def open_log(folder: Path, lab):
    """The lab log in ``folder``: the one there (a resumed run goes on with it) or a new one for ``lab``."""
    from besdrake.transfer.log import LabLog

    return LabLog.open(folder) if (folder / "log.json").is_file() else LabLog.create(folder, lab.description())


def transfer_config(config: dict[str, Any]):
    """The Transferability Approach's settings of a learn configuration (checked before any stage runs);
    :class:`~besdrake.pipeline.config.ConfigError` names a bad value."""
    from besdrake.pipeline.config import ConfigError
    from besdrake.transfer.transferability import PLACEMENT_SD, TransferabilityConfig

    cfg = config["transfer"]
    try:
        return TransferabilityConfig(
            target=tuple(config["refinement"]["target"]), population=int(cfg["population"]),
            max_transfers=int(cfg["max_transfers"]), final_repetitions=int(cfg["final_repetitions"]),
            transfer_choice=str(cfg.get("transfer_choice", "likely")), placement_sd=float(cfg.get("placement_sd", PLACEMENT_SD)),
            futility_p=None if cfg.get("futility_p") is None else float(cfg["futility_p"]),
            futility_transfers=int(cfg.get("futility_transfers", 3)),
        )
    except (TypeError, ValueError) as err:
        raise ConfigError(f"transfer: {err}") from None


def diagnosis_design(config: dict[str, Any], limits=None) -> list:
    """The diagnosis experiment's plans of a learn configuration (checked before any stage runs): ``throws`` plans
    with ``repeats``, ``probes`` tilt probes and ``sideways`` sideways throws (joints 1, 4 and 6 moved, within the
    robot's joint ``limits``; default: those of :func:`learn_scenario`'s robot). :class:`~besdrake.pipeline.config.ConfigError`
    names a bad value."""
    from besdrake.diagnosis import diagnosis_plans
    from besdrake.pipeline.config import ConfigError

    cfg = config["diagnosis"]
    try:
        sideways = int(cfg.get("sideways", 0))
        if int(cfg.get("refine_top", 3)) < 1:
            raise ConfigError(f"diagnosis: refine_top must be an integer >= 1, got {cfg.get('refine_top')!r}")
        if sideways and limits is None:
            limits = learn_scenario(config).robot.limits
        return diagnosis_plans(n=int(cfg["throws"]), repeats=int(cfg["repeats"]), seed=int(config["transfer"]["seed"]), probes=int(cfg.get("probes", 0)),
                               sideways=sideways, limits=limits)
    except (TypeError, ValueError) as err:
        if isinstance(err, ConfigError):
            raise
        raise ConfigError(f"diagnosis: {err}") from None


def _seed_files(folder: Path, best: str | None) -> list[Path]:
    """The refined throws in ``folder``, the refinement's best (file name ``best``) first: the search's template."""
    files = sorted(folder.glob("refined*.dmp.json"))
    return sorted(files, key=lambda f: f.name != best)


def _transfer(ctx: Context, seed_files: list[Path], scenario: str, out: Path) -> dict[str, Any]:
    """The Transferability Approach from ``seed_files`` (best first): the seeds the first one's parameterization
    represents (a throw refined from another imitated throw has another goal velocity and is left out)."""
    from besdrake.imitation import load_dmp, shared_parameterization
    from besdrake.search.refinement import ParameterScaling
    from besdrake.transfer.transferability import TransferabilityApproach

    cfg = ctx.config["transfer"]
    robot = ctx.robot(scenario)
    loaded = [load_dmp(f) for f in seed_files]
    param, kept = shared_parameterization(loaded, robot.joint_names)
    left_out = [f.name for i, f in enumerate(seed_files) if i not in kept]
    if left_out:
        ctx.progress(f"transfer seeds: {seed_files[0].name}" + "".join(f", not {n} (refined from another imitated throw)" for n in left_out))
    dmps = [loaded[i] for i in kept]
    scaling = ParameterScaling.for_dmp(dmps[0], robot.position_limits)
    lab = lab_of(ctx)
    log = open_log(out / "lab_log", lab)
    config = transfer_config(ctx.config)
    with _executor(ctx, scenario) as executor:
        search = TransferabilityApproach(
            lambda theta: param.motion_plan(theta, dt=0.01), np.array([param.to_vector(d) for d in dmps]),
            scaling.scale, scaling.bounds, executor, lab, np.random.default_rng(int(cfg["seed"])), config,
            log=log, out_dir=out, progress=ctx.progress,
        )
        result = search.run()
    summary = result.summary() | {"scenario": scenario, "seeds": [seed_files[i].name for i in kept], "seeds_left_out": left_out}
    if result.best_theta is not None:
        best = param.from_vector(result.best_theta)
        best.save(out / "best.dmp.json")
        param.motion_plan(result.best_theta, dt=0.01).save(out / "best.plan.json")
    write_json(out / "transfers.json", [t.__dict__ for t in result.transfers])
    return summary


def stage_transfer(ctx: Context, out: Path) -> dict[str, Any]:
    refine_dir = ctx.run.root / "04_refine"
    best = ctx.run.done(4, "refine")["summary"].get("best_dmp")
    return _transfer(ctx, _seed_files(refine_dir, best), ctx.config["scenario"], out)


def stage_diagnose(ctx: Context, out: Path) -> dict[str, Any]:
    """Run the diagnosis experiment in the lab, diagnose its log, write the refined scenario."""
    from besdrake.diagnosis import diagnose
    from besdrake.diagnosis.report import write_report
    from besdrake.transfer.log import run_plans

    lab = lab_of(ctx)
    log = open_log(out / "lab_log", lab)
    cfg = ctx.config["diagnosis"]
    plans = diagnosis_design(ctx.config, limits=ctx.robot().limits)
    run_plans(lab, plans, log)
    t0 = time.perf_counter()
    with _executor(ctx, ctx.config["scenario"]) as executor:
        diag = diagnose(log.measurements(), scenario=ctx.config["scenario"], pairs=bool(cfg["pairs"]), executor=executor,
                        refine_top=int(cfg.get("refine_top", 3)))
    seconds = time.perf_counter() - t0
    paths = write_report(diag, out / "report")
    summary = diag.summary()
    rel = {k: (None if paths[k] is None else str(Path(paths[k]).relative_to(ctx.run.root))) for k in ("scenario", "report")}
    return summary | {"diagnosis_s": seconds, "lab_trials": len(log), "refined_scenario": rel["scenario"], "report": rel["report"]}


def refined_scenario(ctx: Context) -> str:
    """The diagnosis's refined scenario (stored relative to the run folder, so a copied or moved run folder
    resumes with its own file), or the configured scenario."""
    done = ctx.run.done(6, "diagnose")
    if not ctx.config["diagnosis"]["enabled"] or done is None or not done["summary"].get("refined_scenario"):
        return ctx.config["scenario"]
    path = Path(done["summary"]["refined_scenario"])
    return str(path if path.is_absolute() else ctx.run.root / path)


def stage_transfer_refined(ctx: Context, out: Path) -> dict[str, Any]:
    """Re-refine the throws in the refined simulation, then the Transferability Approach again."""
    from besdrake.imitation import load_dmp

    scenario = refined_scenario(ctx)
    seeds = [load_dmp(f) for f in sorted((ctx.run.root / "04_refine").glob("refined*.dmp.json"))]
    budget = max(int(ctx.config["refinement"]["evaluations"]) // 2, 20)
    refined = refine_from(ctx, seeds, scenario, out / "refine", budget, "re-refine", scouting=False)
    summary = _transfer(ctx, _seed_files(out / "refine", refined.get("best_dmp")), scenario, out)
    return summary | {"re_refinement": refined}
