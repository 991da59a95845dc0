"""``besdrake lab run``: execute motion plans in a (virtual) lab through the safety gate into a measured-data log."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

COMMAND = ("lab", "run")
HELP = "execute motion plans in a virtual lab (behind the safety gate) and fill a measured-data log; resumes"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--lab", type=Path, required=True, help="lab YAML path, or a built-in lab by name (default_lab, ideal_lab, touchdown_only_lab, "
                        "pick_and_place_lab); its scenario's task builds the lab")
    parser.add_argument("--plans", type=Path, required=True,
                        help="a plan JSON file, a JSON list of plans, or a folder of *.plan.json (sorted by name)")
    parser.add_argument("--seed", type=int, default=None, help="noise seed of the lab (default: the YAML's seed)")
    parser.add_argument("--out", type=Path, required=True, help="log folder (created; an interrupted one is resumed)")
    parser.add_argument("--plugin", type=Path, action="append", default=[],
                        help="Python file that registers further effects (repeatable)")
    parser.add_argument("--quiet", action="store_true", help="no per-trial lines on stderr")


def load_plans(path: str | Path) -> list:
    """Plans from a plan JSON file, a JSON list of plans, or a folder of ``*.plan.json`` files (name order).

    Raises :class:`besdrake.plan.PlanError` naming the file (and list index) for anything malformed."""
    from besdrake.plan import MotionPlan, PlanError

    p = Path(path)
    if p.is_dir():
        files = sorted(p.glob("*.plan.json"))
        if not files:
            raise PlanError(f"no *.plan.json files in the folder {p}")
        plans = []
        for f in files:
            plan = MotionPlan.load(f)
            plan.meta.setdefault("name", f.name[: -len(".plan.json")])
            plans.append(plan)
        return plans
    if not p.is_file():
        raise PlanError(f"plans not found: {p}")
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise PlanError(f"{p} is not valid JSON: {err}") from err
    if isinstance(data, dict):
        plan = MotionPlan.from_dict(data)
        plan.meta.setdefault("name", p.stem.removesuffix(".plan"))
        return [plan]
    if not isinstance(data, list) or not data:
        raise PlanError(f"{p} must hold a motion plan (JSON object) or a non-empty list of them")
    plans = []
    for k, d in enumerate(data):
        try:
            plan = MotionPlan.from_dict(d)
        except PlanError as err:
            raise PlanError(f"{p}, plan {k}: {err}") from err
        plan.meta.setdefault("name", f"{p.stem}[{k}]")
        plans.append(plan)
    return plans


def run(args: argparse.Namespace) -> int:
    import sys

    from besdrake.cli import UserError
    from besdrake.plan import PlanError
    from besdrake.sim.effects import EffectError
    from besdrake.transfer.lab import SafetyGate
    from besdrake.transfer.log import LabLog, LogError, run_plans
    from besdrake.plugins import PluginError, load_plugins
    from besdrake.transfer.lab_config import LabConfigError, open_lab

    try:
        load_plugins(args.plugin)
        virtual = open_lab(args.lab, seed=args.seed)
        plans = load_plans(args.plans)
    except (PluginError, LabConfigError, PlanError) as err:
        raise UserError(str(err)) from None
    lab = SafetyGate(virtual)
    cfg = virtual.config
    run_info = {"seed": cfg.seed, "lab": cfg.name, "plans": len(plans)}
    try:
        if (args.out / "log.json").is_file():
            log = LabLog.open(args.out)
            if log.measurement_type.TASK != lab.measurement_type.TASK:
                raise UserError(f"{args.out} holds {log.measurement_type.TASK or 'throwing'} trials, the lab measures "
                                f"{lab.measurement_type.TASK or 'throwing'} trials: use a new --out folder")
            before = log.header.get("run") or {}
            for key in ("seed", "lab"):
                if before.get(key) != run_info[key]:
                    raise UserError(
                        f"{args.out} was filled with {key}={before.get(key)!r}, not {run_info[key]!r}: "
                        "not the same run (use a new --out folder)"
                    )
        else:
            log = LabLog.create(args.out, lab.description(), run=run_info, measurement=lab.measurement_type)

        def progress(m) -> None:
            if not args.quiet:
                print(f"trial {m.trial}: {m.progress_text()}", file=sys.stderr)

        summary = run_plans(lab, plans, log, progress=progress)
    except (LogError, EffectError) as err:
        raise UserError(str(err)) from None
    counts: dict[str, int] = {}
    for row in log.rows():
        for f in filter(None, row["flags"].split(";")):
            counts[f] = counts.get(f, 0) + 1
    result = {
        "log": str(args.out),
        "trials": summary.total,
        "executed_now": summary.executed,
        "resumed_after": summary.skipped,
        "flag_counts": counts,
    }
    if "success" in log.measurement_type.SUMMARY_COLUMNS:  # a task's measurement that judges success
        result["successes"] = sum(row["success"] == "1" for row in log.rows())
    print(json.dumps(result))
    return 0
