"""``besdrake simulate``: throw once in the simulation and print a summary."""

from __future__ import annotations

import argparse
import json

COMMAND = ("simulate",)
HELP = "simulate a motion plan (default: the default throw) and print where the ball lands"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from besdrake.sim.cliutil import add_common_arguments

    add_common_arguments(parser)
    parser.add_argument("--json", action="store_true", help="print the Outcome summary as JSON")
    parser.add_argument("--full", action="store_true", help="with --json: the whole Outcome (trajectories too)")
    parser.add_argument("--limits", choices=("raise", "flag"), default="raise", help="plans beyond the position limits: error (default) or simulate and flag")
    parser.add_argument("--list-effects", action="store_true", help="list the registered effects and their parameters, then exit")
    parser.add_argument("--record", metavar="FILE.html", help="also write a self-contained meshcat HTML replay of the throw")


def _refuse_unsafe(plan, robot) -> None:
    """The safety gate's timing checks (:class:`besdrake.transfer.lab.SafetyLimits`) for a simulated plan:
    an hour-long plan would hang the simulation, knots closer than the control period are no motion.
    (The start check needs a robot's pose: in simulation the arm is put at the plan's start.)"""
    from besdrake.plan import PlanError
    from besdrake.transfer.safety import SafetyLimits

    problems = SafetyLimits.of(robot).problems(plan)
    if problems:
        raise PlanError("refused by the safety gate's checks: " + "; ".join(problems))


def run(args: argparse.Namespace) -> int:
    from besdrake.cli import UserError
    from besdrake.plan import PlanError
    from besdrake.sim.cliutil import effects_from_args, plan_from_args, scenario_from_args
    from besdrake.sim.effects import EffectError, get_effect, list_effects
    from besdrake._io import json_default
    from besdrake.sim.scenario import ScenarioError
    from besdrake.task import TaskError, get_task

    if args.list_effects:
        info = [get_effect(n).describe() for n in list_effects()]
        if args.json:
            print(json.dumps(info))
        else:
            for e in info:
                params = ", ".join(f"{k}={p['nominal']:g} [{p['low']:g}, {p['high']:g}] {p['unit']}" for k, p in e["params"].items())
                print(f"{e['name']:15s} ({e['applied_via']}) {params}")
        return 0
    try:
        effects = effects_from_args(args.effect)
        scenario = scenario_from_args(args)
        task = get_task(scenario.task)
        rollout = None if args.record else task.make_rollout(scenario)
        plan = plan_from_args(args, task, rollout)
        _refuse_unsafe(plan, scenario.robot)
        if args.record:
            if not str(args.record).endswith((".html", ".htm")):
                raise ValueError(f"--record must be an .html file, got {args.record}")
            from besdrake.sim.record import record_html

            _, outcome = record_html(plan, args.record, scenario=scenario, effects=effects, limits=args.limits, host=args.meshcat_host)
        else:
            outcome = rollout.rollout(plan, effects=effects, limits=args.limits)
    except (PlanError, EffectError, ScenarioError, TaskError, ValueError) as err:
        raise UserError(str(err)) from err
    if args.json:
        print(json.dumps(outcome.to_dict() if args.full else task.summary(outcome), default=json_default))
        return 0 if not outcome.flags.get("sim_failed") else 1
    if not hasattr(outcome, "touchdown"):
        for key, value in task.summary(outcome).items():
            print(f"{key:22s} {value}")
        return 0 if not outcome.flags.get("sim_failed") else 1
    s = outcome.summary()
    if outcome.touchdown is not None:
        print(f"touchdown      x={outcome.touchdown[0]:.3f} m  y={outcome.touchdown[1]:.3f} m  at t={outcome.touchdown_time:.3f} s")
    else:
        print("touchdown      none")
    if outcome.release_time is not None:
        print(f"release        t={outcome.release_time:.3f} s  speed {s['release_speed_mps']:.2f} m/s  at height {outcome.release_position[2]:.3f} m")
    print(f"flags          {', '.join(s['flags']) or 'none'}")
    if outcome.message:
        print(f"message        {outcome.message}")
    if args.record:
        print(f"replay         {args.record}")
    return 0 if not outcome.flags.get("sim_failed") else 1
