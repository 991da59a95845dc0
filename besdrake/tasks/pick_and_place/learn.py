"""``besdrake learn --task pick_and_place``: recordings -> grasp demonstrations -> refined grasps -> lab trials -> report.

The task's stages for :func:`besdrake.pipeline.learn.learn` (each writes into ``RUN/NN_name/`` and is skipped when a
rerun finds it done):

1. ``demonstrations``: every approach/transport pair of the recordings (labeling by the recordings' names,
   segmentation, the shipped 1-NN classifier) as a grasp demonstration in the task frame; a recording or pair that
   cannot be used is listed with the reason, the others go on;
2. ``refine``: per demonstration (at most ``refine.max_demonstrations``), the grasp skill imitated, adapted to the
   scene and refined with CMA-ES in simulation until a rollout succeeds (:func:`~besdrake.tasks.pick_and_place.refine.refine_grasp`);
3. ``lab``: each refined grasp that succeeded in simulation, planned and executed ``lab.trials`` times in the virtual
   lab behind the safety gate, every trial in the lab log before the next;
4. ``template``: a behaviour template over the box's place on the shelf from the best refined grasp, trained and
   tested at other places in simulation (:mod:`~besdrake.tasks.pick_and_place.template`);
5. ``report``: ``report.md``, the run's figures (``summary.json``) and a meshcat HTML replay of the best grasp.

Default demonstration: the recording shipped with the package (``data/``, with its licence).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from besdrake._io import write_json, write_text

DATA_DIR = Path(__file__).resolve().parent / "data"
LEARN_CONFIG = Path(__file__).resolve().parent / "learn.yaml"


def _recordings(source: str | None) -> list[Path]:
    """The TSV files of ``source`` (a folder or one file; None: the shipped recording)."""
    path = DATA_DIR if source in (None, "", "shipped") else Path(source)
    if path.is_file():
        return [path]
    if not path.is_dir():
        raise FileNotFoundError(f"demonstrations: {path} is neither a recording nor a folder")
    files = sorted(path.glob("*.tsv"))
    if not files:
        raise FileNotFoundError(f"demonstrations: no .tsv recordings in {path}")
    return files


def stage_demonstrations(ctx, out: Path) -> dict[str, Any]:
    """Stage 1: grasp demonstrations of every recording, each saved as ``.npz``; the unusable ones listed."""
    from besdrake.tasks.pick_and_place.demonstrations import extract_demonstrations

    used, problems = [], []
    for f in _recordings(ctx.config["demonstrations"].get("source")):
        res = extract_demonstrations(f)
        for i, d in enumerate(res.demonstrations):
            name = f"{f.stem}_{i}"
            d.to_npz(out / f"{name}.npz")
            used.append(name)
        problems += [{"file": f.name, "problem": p} for p in res.problems]
        problems += [{"file": f.name, "rejected": r.to_dict()} for r in res.rejected]
    write_json(out / "demonstrations.json", {"used": used, "problems": problems})
    ctx.progress(f"  {len(used)} grasp demonstrations, {len(problems)} problems")
    return {"demonstrations_used": len(used), "problems": len(problems)}


def stage_refine(ctx, out: Path) -> dict[str, Any]:
    """Stage 2: every demonstration imitated, adapted to the scene and refined in simulation."""
    from besdrake.tasks.pick_and_place.demonstrations import GraspDemonstration
    from besdrake.tasks.pick_and_place.imitation import GraspImitationError, GraspSkill
    from besdrake.tasks.pick_and_place.refine import RefineSettings, refine_grasp
    from besdrake.tasks.pick_and_place.rollout import PickPlaceRollout
    from besdrake.tasks.pick_and_place.skill_plan import SkillPlanner

    cfg = ctx.config["refine"]
    demo_dir = ctx.run.stage_dir(1, "demonstrations")
    files = sorted(demo_dir.glob("*.npz"))[: int(cfg.get("max_demonstrations") or 10**6)]
    planner = SkillPlanner.for_rollout(PickPlaceRollout(ctx.config["scenario"]))
    settings = RefineSettings(max_generations=int(cfg["max_generations"]), popsize=cfg.get("popsize"),
                              sigma0=float(cfg["sigma0"]), workers=int(ctx.config.get("workers", 1)),
                              seed=int(cfg["seed"]), weights=bool(cfg.get("weights", False)),
                              box_jitter=float(cfg.get("box_jitter", 0.0)))
    rows = []
    for f in files:
        try:
            skill = planner.adapt(GraspSkill.from_demonstration(GraspDemonstration.from_npz(f)))
        except GraspImitationError as err:
            rows.append({"demonstration": f.stem, "success": False, "error": str(err)})
            continue
        t0 = time.perf_counter()
        res = refine_grasp(skill, ctx.config["scenario"], out / f.stem, settings)
        rows.append({"demonstration": f.stem, **res.summary(), "wall_s": time.perf_counter() - t0})
        ctx.progress(f"  {f.stem}: {'success' if res.success else 'no success'} after {res.episodes} episodes "
                     f"({res.best_message})")
    write_json(out / "refinement.json", rows)
    hits = [r["episodes_to_success"] for r in rows if r.get("success")]
    return {"demonstrations_refined": len(rows), "success_rate_sim": len(hits) / len(rows) if rows else 0.0,
            "median_episodes_to_success": float(np.median(hits)) if hits else None,
            "initial_successes": sum(bool(r.get("initial_success")) for r in rows)}


def stage_lab(ctx, out: Path) -> dict[str, Any]:
    """Stage 3: the refined grasps that succeeded in simulation, ``lab.trials`` times each in the lab."""
    from besdrake.tasks.pick_and_place.imitation import GraspSkill
    from besdrake.tasks.pick_and_place.skill_plan import SkillPlanner
    from besdrake.transfer.lab import SafetyGate
    from besdrake.transfer.lab_config import open_lab
    from besdrake.transfer.log import LabLog, run_plans

    refine_dir = ctx.run.stage_dir(2, "refine")
    virtual = open_lab(_lab_config(ctx), seed=int(ctx.config["lab_trials"]["seed"]))
    lab = SafetyGate(virtual)
    planner = SkillPlanner.for_rollout(virtual.rollout)
    plans = []
    for row in _read_json(refine_dir / "refinement.json"):
        if row.get("success"):
            skill = GraspSkill.from_dict(_read_json(refine_dir / row["demonstration"] / "skill.json"))
            plans += [planner.plan(skill).plan] * int(ctx.config["lab_trials"]["per_grasp"])
    if not plans:
        return {"trials": 0, "success_rate_lab": 0.0, "place_error_m": None, "note": "no grasp succeeded in simulation"}
    log_dir = out / "log"
    log = LabLog.open(log_dir) if (log_dir / "log.json").is_file() else LabLog.create(
        log_dir, lab.description(), run={"stage": "lab"}, measurement=lab.measurement_type)
    run_plans(lab, plans, log)
    rows = log.rows()
    errors = [float(r["place_error"]) for r in rows if r.get("place_error") not in (None, "", "nan")]
    return {"trials": len(rows), "success_rate_lab": sum(r["success"] == "1" for r in rows) / len(rows),
            "place_error_m": float(np.median(errors)) if errors else None}


def stage_template(ctx, out: Path) -> dict[str, Any]:
    """Stage 4: a behaviour template over the box's place on the shelf, from the best refined grasp: trained at
    ``template.train_contexts`` places of ``template.region`` (corners and centre first), tested at
    ``template.test_contexts`` other, seeded places in simulation."""
    from besdrake.tasks.pick_and_place.refine import RefineSettings
    from besdrake.tasks.pick_and_place.template import (context_grid, evaluate_grasp_template, learn_grasp_template,
                                                        random_contexts)

    cfg = ctx.config["template"]
    best = _best_refined(ctx)
    if best is None:
        return {"template_success_rate_sim": None, "note": "no grasp succeeded in simulation"}
    name, base = best
    train = context_grid(cfg["region"], int(cfg["train_contexts"]))
    test = random_contexts(cfg["region"], int(cfg["test_contexts"]), np.random.default_rng(int(cfg["seed"])))
    settings = RefineSettings(max_generations=int(cfg["max_generations"]), workers=int(ctx.config.get("workers", 1)),
                              seed=int(cfg["seed"]))
    template = learn_grasp_template(base, ctx.config["scenario"], train, out, settings)
    ev = evaluate_grasp_template(template, ctx.config["scenario"], test)
    write_json(out / "evaluation.json", ev.summary())
    training = _read_json(out / "training.json")
    ctx.progress(f"  template from {name}: {sum(r['initial_success'] for r in training)} of "
                 f"{len(training)} training places succeeded as carried over; test {ev.success_rate:.0%}")
    return {"template_base": name, "template_train_contexts": len(training),
            "template_train_initial_successes": sum(r["initial_success"] for r in training),
            "template_success_rate_sim": ev.success_rate, "template_place_error_m": ev.summary()["median_place_error_m"]}


def _lab_config(ctx) -> dict[str, Any]:
    """The configured lab's YAML as a mapping, with the run's scenario (its robot) in place of the lab's own."""
    import yaml

    from besdrake.transfer.lab_config import resolve_lab_path

    path = resolve_lab_path(ctx.config["lab"])
    data = yaml.safe_load(path.read_text())
    data["scenario"] = str(Path(ctx.config["scenario"]).resolve()) if Path(ctx.config["scenario"]).is_file() \
        else ctx.config["scenario"]
    data.pop("robot", None)
    return data


def _read_json(path: Path):
    return json.loads(Path(path).read_text())


def stage_report(ctx, out: Path) -> dict[str, Any]:
    """Stage 4: ``report.md`` in the run folder and the run's figures."""
    from besdrake.sim.scenario import load_scenario

    rec = {name: ctx.run.done(i, name) for i, name in enumerate(("demonstrations", "refine", "lab", "template"), 1)}
    s = {k: (v or {}).get("summary", {}) for k, v in rec.items()}
    summary = {
        "task": "pick_and_place", "robot": load_scenario(ctx.config["scenario"]).robot.name,
        "demonstrations_used": s["demonstrations"].get("demonstrations_used", 0),
        "success_rate_sim": s["refine"].get("success_rate_sim"), "success_rate_lab": s["lab"].get("success_rate_lab"),
        "median_episodes_to_success": s["refine"].get("median_episodes_to_success"),
        "place_error_m": s["lab"].get("place_error_m"), "lab_trials": s["lab"].get("trials"),
        "template_success_rate_sim": s["template"].get("template_success_rate_sim"),
        "template_place_error_m": s["template"].get("template_place_error_m"),
        "wall_s": sum(float((v or {}).get("seconds", 0.0)) for v in rec.values()),
    }
    summary["replays"] = _replays(ctx, out)
    write_json(out / "summary.json", summary)
    write_text(ctx.run.root / "report.md", _report_text(summary, rec))
    return summary


def _replays(ctx, out: Path) -> list[str]:
    """A meshcat HTML replay of the best refined grasp in simulation (path relative to the run folder), if any."""
    from besdrake.sim.record import record_html
    from besdrake.tasks.pick_and_place.rollout import PickPlaceRollout
    from besdrake.tasks.pick_and_place.skill_plan import SkillPlanner

    best = _best_refined(ctx)
    if best is None:
        return []
    name, skill = best
    plan = SkillPlanner.for_rollout(PickPlaceRollout(ctx.config["scenario"])).plan(skill).plan
    path, _ = record_html(plan, out / f"replay_{name}.html", ctx.config["scenario"], fps=30.0, limits="flag")
    return [str(path.relative_to(ctx.run.root))]


def _best_refined(ctx):
    """``(demonstration, skill)`` of the refine stage's grasp that succeeded with the highest reward, or None."""
    from besdrake.tasks.pick_and_place.imitation import GraspSkill

    table = ctx.run.stage_dir(2, "refine") / "refinement.json"
    hits = [r for r in _read_json(table) if r.get("success")] if table.is_file() else []
    if not hits:
        return None
    best = max(hits, key=lambda r: r["best_reward"])
    return best["demonstration"], GraspSkill.from_dict(_read_json(table.parent / best["demonstration"] / "skill.json"))


def _report_text(summary: dict[str, Any], rec: dict[str, Any]) -> str:
    lines = ["# besdrake learn: pick-and-place", "", f"Robot: {summary['robot']}", "",
             "| stage | time (s) | figures |", "| --- | --- | --- |"]
    for name, r in rec.items():
        if r:
            figures = ", ".join(f"{k} {v}" for k, v in r["summary"].items())
            lines.append(f"| {name} | {r['seconds']:.1f} | {figures} |")
    lines += ["", "| figure | value |", "| --- | --- |"] + [f"| {k} | {v} |" for k, v in summary.items()
                                                          if k != "replays"]
    if summary.get("replays"):
        lines += ["", "Replays (meshcat, self-contained HTML: open in a browser): "
                  + ", ".join(f"[{Path(p).name}]({p})" for p in summary["replays"])]
    return "\n".join(lines) + "\n"


STAGES = [("demonstrations", stage_demonstrations), ("refine", stage_refine), ("lab", stage_lab),
          ("template", stage_template), ("report", stage_report)]
