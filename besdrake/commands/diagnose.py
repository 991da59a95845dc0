"""``besdrake diagnose LOGDIR``: what the simulation gets wrong against a lab log, why, the refined scenario, the gain."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

COMMAND = ("diagnose",)
HELP = "compare a lab log with the simulation, name the cause (effect fit + BIC), write a refined scenario and the held-out gain"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("logdir", type=Path, nargs="*", default=[],
                        help="measured-data log folder(s) (besdrake lab run --out ...); several are diagnosed as one log (e.g. a first log and its --after follow-up)")
    parser.add_argument("--design", type=Path, default=None, metavar="DIR",
                        help="instead of diagnosing: write a diagnosis plan set (diverse throws with repeats) as DIR/NNN_*.plan.json for 'besdrake lab run --plans DIR'")
    parser.add_argument("--throws", type=int, default=25, help="with --design: number of throws (default 25)")
    parser.add_argument("--repeats", type=int, default=8, help="with --design: how many of them repeat an earlier plan (default 8)")
    parser.add_argument("--probes", type=int, default=None,
                        help="with --design: how many of them are slow tilt probes that show the ball-scoop friction (default 2)")
    parser.add_argument("--sideways", type=int, default=None,
                        help="with --design: how many of the distinct throws are sideways throws that also move joints 1, 4 and 6 (default 5)")
    parser.add_argument("--optimal", action="store_true",
                        help="with --design: choose the distinct plans D-optimally from a pool of the task's random designs (the simulation's "
                             "sensitivities to every candidate effect, computed once per scenario and cached; see besdrake.diagnosis.optimal_design)")
    parser.add_argument("--after", type=Path, default=None, metavar="LOGDIR",
                        help="with --design: a follow-up to this first log: diagnose it, then choose the plans that tell its leading causes apart "
                             "(D-optimal for their parameters at the named cause's fit, given the logged plans; see besdrake.diagnosis.discrimination)")
    parser.add_argument("--out", type=Path, default=None, help="folder for report.md, diagnosis.json, refined_scenario.yaml, figures (default: runs/diagnosis/<log name>)")
    parser.add_argument("--scenario", default=None,
                        help="the simulation the lab is compared with (name or YAML path; default: the log's task's default scenario, 'nominal' for throwing)")
    parser.add_argument("--candidates", default=None, help="comma-separated effect names to consider (default: every registered effect that acts on the scenario's task)")
    parser.add_argument("--no-pairs", action="store_true", help="fit single effects only (no pairs)")
    parser.add_argument("--plugin", action="append", default=[], metavar="FILE.py", help="load a Python file that registers further effects (repeatable)")
    from besdrake.sim.cliutil import add_backend_arguments

    add_backend_arguments(parser)
    parser.add_argument("--folds", type=int, default=3, help="K of the held-out (K-fold by plan) gain (default 3)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the folds and the bootstrap")
    parser.add_argument("--placement-sd", type=float, default=None, metavar="M",
                        help="throw-to-throw scatter of the ball's placement in the scoop, m per axis (default 0.002, the virtual lab's; "
                             "0: compare with the ball always centred)")
    parser.add_argument("--no-figures", action="store_true", help="do not write PNG figures")
    parser.add_argument("--json", action="store_true", help="print the machine-readable summary as JSON")


def run(args: argparse.Namespace) -> int:
    from besdrake.cli import UserError
    from besdrake.diagnosis import DiagnosisError, diagnose
    from besdrake.diagnosis.report import write_report
    from besdrake.sim.cliutil import executor_from_args
    from besdrake.sim.effects import EffectError, get_effect
    from besdrake.sim.executors import ExecutorError
    from besdrake.sim.scenario import ScenarioError, load_scenario

    if args.after is not None and args.design is None:
        raise UserError("--after LOGDIR designs a follow-up: give --design DIR too")
    if args.optimal and args.after is not None:
        raise UserError("--optimal and --after are two designs: give one")
    after = _read_log(args.after) if args.design is not None and args.after is not None else None
    if after is not None and args.scenario is None:
        args.scenario = _log_scenario(after)
    if args.design is not None and args.scenario is not None and _task_of(args.scenario) != "throwing":
        return _design_task(args, after)
    if args.design is not None:
        return _design_throwing(args, after)
    if not args.logdir:
        raise UserError("give a log folder to diagnose (or --design DIR to write a plan set)")
    if args.workers < 1:
        raise UserError(f"--workers must be >= 1, got {args.workers}")
    if args.folds < 2:
        raise UserError(f"--folds must be >= 2, got {args.folds}")
    try:
        from besdrake.plugins import PluginError, load_plugins

        load_plugins(args.plugin)
    except PluginError as err:
        raise UserError(str(err)) from None
    measurements = _read_logs(args.logdir)
    if args.scenario is None:
        args.scenario = _log_scenario(measurements)
    candidates = None if args.candidates is None else [c.strip() for c in args.candidates.split(",") if c.strip()]
    try:
        scenario = load_scenario(args.scenario)
        names = candidates if candidates is not None else None
        if names is not None:
            for n in names:
                get_effect(n)
        # Plugin effects reach the simulation workers too: the executors load this process's plugins in each.
        with executor_from_args(args, scenario) as executor:
            diag = diagnose(measurements, scenario=scenario, candidates=candidates, pairs=not args.no_pairs, executor=executor,
                            folds=args.folds, seed=args.seed,
                            **({} if args.placement_sd is None else {"placement_sd": args.placement_sd}))
    except (DiagnosisError, EffectError, ScenarioError, ExecutorError) as err:
        raise UserError(str(err)) from None
    out = args.out or Path("runs") / "diagnosis" / "+".join(Path(d).resolve().name for d in args.logdir)
    paths = write_report(diag, out, figures=not args.no_figures)
    if args.json:
        print(diag.to_json())
    else:
        _print_summary(diag, paths)
    return 0


def _design_throwing(args: argparse.Namespace, after: list | None) -> int:
    """``--design`` for throwing: the diagnosis throws with tilt probes and sideways throws (``after``: the first log
    of ``--after``)."""
    from besdrake.cli import UserError
    from besdrake.sim.scenario import load_scenario

    from besdrake.diagnosis import diagnosis_plans
    from besdrake.tasks.throwing.diagnosis.design import DEFAULT_PROBES, DEFAULT_SIDEWAYS

    probes = DEFAULT_PROBES if args.probes is None else args.probes
    sideways = DEFAULT_SIDEWAYS if args.sideways is None else args.sideways
    if args.sideways is None:  # the default fits the design's distinct throws
        sideways = max(0, min(sideways, args.throws - args.repeats - probes))
    scenario = args.scenario or "nominal"
    try:
        plans = _chosen_design(args, after, scenario, {"probes": probes, "sideways": sideways},
                               lambda: diagnosis_plans(args.throws, args.repeats, seed=args.seed, probes=probes, sideways=sideways,
                                                       limits=load_scenario(scenario).robot.limits))
    except ValueError as err:
        raise UserError(str(err)) from None
    _write_plans(plans, args.design)
    print(f"wrote {len(plans)} plans ({args.repeats} repeats, {probes} tilt probes, {sideways} sideways throws) to {args.design}")
    return 0


def _print_summary(diag, paths: dict) -> None:
    """The verdict, what the log cannot tell, the held-out gain, where the report went, timings."""
    print(f"{diag.verdict}")
    print(f"explained: {diag.explained} (confidence {diag.confidence}); best: {diag.best.to_dict()['effect'] if diag.best else 'none'}")
    for a in diag.cannot_tell:
        print(f"cannot tell nominal from {a.describe()}: {a.recommendation}")
    if diag.gain:
        g = diag.gain
        from besdrake.diagnosis.trials import model_for

        what = model_for(diag.scenario).outcome if diag.scenario is not None else "outcome"
        print(f"held-out median {what} disparity: {g.median_disparity_before_m:.3f} m -> {g.median_disparity_after_m:.3f} m "
              f"(95% CI {g.ci_after_m[0]:.3f}-{g.ci_after_m[1]:.3f} m, {g.n_heldout} trials)")
    print(f"report: {paths['report']}")
    print(f"refined scenario: {paths['scenario']}")
    print(json.dumps({"timings_s": {k: round(v, 1) for k, v in diag.timings.items()}, "rollouts": diag.n_rollouts}))


def _task_of(scenario: str) -> str | None:
    from besdrake.cli import UserError
    from besdrake.sim.scenario import ScenarioError, load_scenario

    try:
        return load_scenario(scenario).task or "throwing"
    except ScenarioError as err:
        raise UserError(str(err)) from None


def _design_task(args: argparse.Namespace, after: list | None) -> int:
    """``--design`` for a task other than throwing: its own designed experiment (``--throws`` trials, ``--repeats``;
    ``after``: the first log of ``--after``)."""
    from besdrake.cli import UserError
    from besdrake.diagnosis.trials import model_for
    from besdrake.sim.scenario import load_scenario
    from besdrake.task import TaskError

    scen = load_scenario(args.scenario)
    try:
        model = model_for(scen)
        plans = _chosen_design(args, after, scen, {"scenario": args.scenario},
                               lambda: model.design_experiments(args.throws, args.repeats, seed=args.seed, limits=scen.robot.limits,
                                                                scenario=args.scenario))
    except (TaskError, ValueError) as err:
        raise UserError(str(err)) from None
    _write_plans(plans, args.design)
    print(f"wrote {len(plans)} {model.plural()} ({args.repeats} repeats) to {args.design}")
    return 0


def _chosen_design(args: argparse.Namespace, after: list | None, scenario, options: dict, random_design) -> list:
    """The plans of the design asked for: the follow-up to ``after`` (``--after``), the D-optimal one (``--optimal``)
    or the task's random design (``random_design()``); ``options``: the task's design keywords."""
    if after is not None:
        return _follow_up(args, after, scenario, options)
    if args.optimal:
        return _optimal(args, scenario, options)
    return random_design()


def _gain_summary(gain: dict[str, float]) -> str:
    """Each parameter's information against the task's random design: the median and the three least."""
    import numpy as np

    finite = sorted(((k, v) for k, v in gain.items() if np.isfinite(v)), key=lambda kv: kv[1])
    median = np.median([v for _, v in finite]) if finite else float("nan")
    return f"x{median:.2f} (median), least " + ", ".join(f"{k} x{v:.2f}" for k, v in finite[:3])


def _optimal(args: argparse.Namespace, scenario, options: dict) -> list:
    """``--optimal``: the D-optimal design's plans; prints what it gains over the task's random design."""
    from besdrake.cli import UserError
    from besdrake.diagnosis.optimal_design import optimal_plans
    from besdrake.sim.cliutil import executor_from_args
    from besdrake.sim.executors import ExecutorError
    from besdrake.sim.scenario import ScenarioError

    try:
        with executor_from_args(args, scenario=scenario) as ex:
            d = optimal_plans(args.throws, args.repeats, seed=args.seed, scenario=scenario, executor=ex, design_options=options)
    except (ValueError, ExecutorError, ScenarioError) as err:
        raise UserError(str(err)) from None
    print(f"D-optimal design: log det {d.log_det:.1f} against {d.reference_log_det:.1f} for the task's random design; each parameter's "
          f"information given the others {_gain_summary(d.gain)}")
    return d.plans


def _follow_up(args: argparse.Namespace, measurements: list, scenario, options: dict) -> list:
    """``--after LOGDIR``: diagnose the first log (``measurements``), then the plans that tell its leading causes apart
    (:func:`~besdrake.diagnosis.discrimination.informative_plans`); prints which and what they add against the task's
    random design."""
    from besdrake.cli import UserError
    from besdrake.diagnosis import DiagnosisError, diagnose
    from besdrake.diagnosis.discrimination import informative_plans
    from besdrake.sim.cliutil import executor_from_args
    from besdrake.sim.executors import ExecutorError
    from besdrake.sim.scenario import ScenarioError, load_scenario

    try:
        scen = load_scenario(scenario) if isinstance(scenario, str) else scenario
        with executor_from_args(args, scenario=scen) as ex:
            first = diagnose(measurements, scenario=scen, executor=ex, seed=args.seed,
                             **({} if args.placement_sd is None else {"placement_sd": args.placement_sd}))
            d = informative_plans(first, [m.plan for m in measurements], args.throws, args.repeats, ex, seed=args.seed, design_options=options)
    except (DiagnosisError, ValueError, ExecutorError, ScenarioError) as err:
        raise UserError(str(err)) from None
    print(f"first log: {first.verdict}")
    print(f"follow-up to tell {d.leader} from {', '.join(d.rivals)}: each of their parameters' information given the others and the first log, "
          f"against the task's random design, {_gain_summary(d.gain)}")
    return d.plans


def _read_log(folder) -> list:
    """The measurements of a log folder; a :class:`~besdrake.cli.UserError` where it cannot be read."""
    from besdrake.cli import UserError
    from besdrake.transfer.log import read_log

    try:
        return read_log(folder)
    except (OSError, ValueError) as err:
        raise UserError(f"cannot read the log {folder}: {err}") from None


def _read_logs(folders: list) -> list:
    """The measurements of several log folders as one log, numbered on in memory from one folder to the next (the
    files are not touched)."""
    import dataclasses

    out: list = []
    for folder in folders:
        offset = len(out)
        out += [dataclasses.replace(m, trial=m.trial + offset) for m in _read_log(folder)]
    return out


def _log_scenario(measurements: list) -> str:
    """The default scenario of the log's task ('nominal' for throwing)."""
    from besdrake.task import get_task

    tasks = sorted({type(m).TASK for m in measurements if type(m).TASK is not None})
    return get_task(tasks[0]).default_scenario if tasks else "nominal"


def _write_plans(plans: list, folder) -> None:
    """The designed plans as ``NNN_<name>.plan.json`` in ``folder`` (created)."""
    folder.mkdir(parents=True, exist_ok=True)
    for i, p in enumerate(plans):
        p.save(folder / f"{i:03d}_{p.meta['name']}.plan.json")
