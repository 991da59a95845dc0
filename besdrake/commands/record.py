"""``besdrake record``: write a self-contained meshcat HTML replay of one throw."""

from __future__ import annotations

import argparse

COMMAND = ("record",)
HELP = "simulate a throw and write a self-contained meshcat HTML replay (offline)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from besdrake.sim.cliutil import add_common_arguments

    add_common_arguments(parser)
    parser.add_argument("--out", required=True, help="HTML file to write")
    parser.add_argument("--fps", type=float, default=60.0, help="frames per second of the replay")


def run(args: argparse.Namespace) -> int:
    from besdrake.cli import UserError
    from besdrake.plan import PlanError
    from besdrake.sim.cliutil import effects_from_args, plan_from_args, scenario_from_args
    from besdrake.sim.effects import EffectError
    from besdrake.sim.scenario import ScenarioError

    if not str(args.out).endswith((".html", ".htm")):
        raise UserError(f"--out must be an .html file, got {args.out}")
    if not 1.0 <= args.fps <= 240.0:
        raise UserError(f"--fps must be in [1, 240], got {args.fps}")
    try:
        from besdrake.sim.record import record_html

        from besdrake.commands.simulate import _refuse_unsafe

        plan = plan_from_args(args)
        scenario = scenario_from_args(args)
        _refuse_unsafe(plan, scenario.robot)
        path, outcome = record_html(plan, args.out, scenario=scenario, effects=effects_from_args(args.effect), fps=args.fps, host=args.meshcat_host)
    except (PlanError, EffectError, ScenarioError, ValueError) as err:
        raise UserError(str(err)) from err
    td = "none" if outcome.touchdown is None else f"x={outcome.touchdown[0]:.3f} m y={outcome.touchdown[1]:.3f} m"
    print(f"wrote {path} (touchdown {td})")
    return 0
