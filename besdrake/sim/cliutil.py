"""Helpers shared by the ``simulate`` and ``record`` commands: effect options and plan loading."""

from __future__ import annotations

import argparse

from besdrake.plan import MotionPlan
from besdrake.sim.effects import EffectError, get_effect


def parse_effect_option(text: str) -> tuple[str, dict[str, float]]:
    """Parse ``NAME`` or ``NAME:key=val,key=val`` into ``(name, {key: value})``; :class:`EffectError` if malformed."""
    name, _, rest = text.partition(":")
    name = name.strip()
    if not name:
        raise EffectError(f"--effect {text!r}: missing effect name (NAME:key=val,...)")
    get_effect(name)  # unknown name -> EffectError listing the known ones
    values: dict[str, float] = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, val = item.partition("=")
        if not eq:
            raise EffectError(f"--effect {text!r}: {item!r} is not key=value")
        try:
            values[key.strip()] = float(val)
        except ValueError:
            raise EffectError(f"--effect {text!r}: value of {key.strip()!r} is not a number: {val!r}") from None
    return name, values


def effects_from_args(options: list[str] | None) -> dict[str, dict[str, float]]:
    """All ``--effect`` options as one effects dict (later options update earlier ones)."""
    effects: dict[str, dict[str, float]] = {}
    for text in options or []:
        name, values = parse_effect_option(text)
        effects.setdefault(name, {}).update(values)
    return effects


def add_common_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--plan", help="motion plan JSON (MotionPlan.save); default: the task's default plan")
    parser.add_argument("--amplitude", type=float, default=None,
                        help="amplitude of the task's default plan (no --plan; tasks that shape their default plan)")
    parser.add_argument("--yaw", type=float, default=0.0, help="joint-1 angle of the task's default plan (rad)")
    parser.add_argument("--scenario", default="nominal", help="scenario name in besdrake/diagrams/ or a YAML path")
    parser.add_argument("--robot", default=None, help="robot: a built-in name or a robot YAML path (default: the scenario's)")
    parser.add_argument("--effect", action="append", metavar="NAME:key=val,...", help="physical effect, repeatable (see --list-effects)")
    parser.add_argument("--meshcat-host", default="localhost", metavar="HOST",
                        help="interface the meshcat server of a replay listens on (default localhost; '*' or 0.0.0.0 opens it to the network)")


def scenario_from_args(args: argparse.Namespace):
    """The ``--scenario``, on the ``--robot`` when one is given (:class:`ScenarioError` otherwise; a
    :class:`~besdrake.robot.RobotError` when that robot cannot do the scenario's task, e.g. an arm without the end effector the task needs)."""
    from besdrake.sim.scenario import load_scenario
    from besdrake.task import get_task

    scenario = load_scenario(args.scenario)
    if not getattr(args, "robot", None):
        return scenario
    scenario = scenario.with_robot(args.robot)
    get_task(scenario.task).check_robot(scenario.robot)
    return scenario


def plan_from_args(args: argparse.Namespace, task=None, rollout=None) -> MotionPlan:
    """``--plan``; else ``task``'s (default: the default task's) default plan in ``rollout``, shaped by
    ``--amplitude``/``--yaw`` where given (:meth:`besdrake.task.Task.default_plan`)."""
    if args.plan:
        if args.amplitude is not None:
            raise ValueError("give either --plan or --amplitude, not both")
        return MotionPlan.load(args.plan)
    if task is None:
        from besdrake.task import DEFAULT_TASK, get_task

        task = get_task(DEFAULT_TASK)
    shape = {k: v for k, v in (("amplitude", args.amplitude), ("yaw", args.yaw)) if v is not None and (k != "yaw" or v)}
    return task.default_plan(rollout, **shape)


def add_backend_arguments(parser: argparse.ArgumentParser, default: str = "process", workers: int = 2) -> None:
    """``--backend serial|process|ray``, ``--workers N`` and ``--ray ADDRESS`` (implies the ray backend)."""
    parser.add_argument("--backend", choices=("serial", "process", "ray"), default=default,
                        help=f"rollout executor (default {default}); ray: Ray actors, see --ray")
    parser.add_argument("--workers", type=int, default=workers, help=f"worker processes / Ray actors (default {workers})")
    parser.add_argument("--ray", default=None, metavar="ADDRESS",
                        help="run rollouts on this Ray cluster ('auto': the one started with 'ray start' on this machine; "
                             "needs besdrake[cluster]); without it --backend ray starts a local Ray bound to 127.0.0.1")


def executor_from_args(args: argparse.Namespace, scenario, limits: str = "flag"):
    """The executor ``add_backend_arguments`` asked for (:class:`~besdrake.sim.executors.ExecutorError` or
    :class:`~besdrake.sim.scenario.ScenarioError` for a bad choice or scenario)."""
    from besdrake.sim.executors import ExecutorError, make_executor

    backend = "ray" if getattr(args, "ray", None) else args.backend
    workers = int(args.workers)
    if workers < 1:
        raise ExecutorError(f"--workers must be >= 1, got {workers}")
    if backend == "ray":
        return make_executor("ray", workers=workers, scenario=scenario, limits=limits, address=getattr(args, "ray", None))
    if backend == "process" and workers > 1:
        return make_executor("process", workers=workers, scenario=scenario, limits=limits)
    return make_executor("serial", scenario=scenario, limits=limits)
