"""``besdrake learn``: the main job, from demonstrations to a template pool (see :mod:`besdrake.pipeline.learn`)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

COMMAND = ("learn",)
HELP = "the whole platform: labeling, segmentation, imitation, refinement, transfer, diagnosis, templates"

#: Rough share of each stage in a default run's time (for the progress bar's estimate of the time left).
_WEIGHTS = {"label": 1, "segment": 2, "imitate": 4, "refine": 10, "transfer": 20, "diagnose": 25,
            "transfer_refined": 25, "template": 10, "pool": 1, "report": 2}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("runs/learn"), help="run folder (rerun the same command to resume)")
    parser.add_argument("--config", type=Path, default=None, help="YAML with any of the settings of the task's learn configuration (default task: besdrake/tasks/throwing/learn.yaml)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override one setting, e.g. --set refinement.evaluations=500 (repeatable)")
    parser.add_argument("--quick", action="store_true", help="smoke profile: every stage on a small budget (about a minute or two)")
    parser.add_argument("--demonstrations", default=None, help="folder of your own TSV/C3D recordings (default: the synthetic demonstrator)")
    parser.add_argument("--task", default=None, help="the skill to learn (default: throwing; see besdrake/tasks)")
    parser.add_argument("--robot", default=None, help="robot: a built-in name or a robot YAML path (default: the scenario's)")
    parser.add_argument("--lab", default=None, help="lab YAML path or built-in lab name (default: default_lab)")
    parser.add_argument("--workers", type=int, default=None, help="simulation processes (default 2)")
    parser.add_argument("--ray", default=None, metavar="ADDRESS", help="run rollouts on a Ray cluster (e.g. 'auto'; needs besdrake[cluster])")
    parser.add_argument("--meshcat-host", default="localhost", metavar="HOST",
                        help="interface the meshcat server of the report's replays listens on (default localhost; '*' opens it)")
    parser.add_argument("--stage", action="append", default=None, help="run only these stages (repeatable)")
    parser.add_argument("--json", action="store_true", help="print every stage's summary as one JSON object")


def _input_errors() -> tuple[type[Exception], ...]:
    """The errors a stage raises for bad input (a recording, a lab, a scenario, a damaged run folder):
    each names the file and the problem, so it is printed as one line."""
    from besdrake.mocap.labeling import LabelingError
    from besdrake.mocap.preprocess import PreprocessError
    from besdrake.mocap.recording import MocapFormatError
    from besdrake.pipeline.run import RunError
    from besdrake.plan import PlanError
    from besdrake.search.loop import ResumeError
    from besdrake.segmentation import SegmentationError
    from besdrake.sim.effects import EffectError
    from besdrake.sim.scenario import ScenarioError
    from besdrake.transfer.log import LogError
    from besdrake.plugins import PluginError
    from besdrake.tasks.throwing.lab import LabConfigError

    return (MocapFormatError, PreprocessError, LabelingError, SegmentationError, PlanError, ScenarioError, EffectError,
            LogError, PluginError, LabConfigError, ResumeError, RunError, FileNotFoundError)


def _check_resumable(run_folder, out) -> None:
    """A run begun by an earlier besdrake goes on with its own configuration only where this version can read it
    (the task's checks of its settings pass), else a clear error."""
    from besdrake.cli import UserError
    from besdrake.pipeline.config import ConfigError
    from besdrake.pipeline.learn import learn_scenario
    from besdrake.task import get_task

    config = run_folder.config
    try:
        learn_scenario(config)
        get_task(config["task"]).check_learn_config(config)
    except (ConfigError, KeyError, TypeError, ValueError) as err:
        raise UserError(f"{out} was begun by an earlier besdrake whose configuration this version cannot resume ({err!s}); "
                        "finish it with that version, or choose a new --out folder") from None


def run(args: argparse.Namespace) -> int:
    from besdrake.cli import UserError
    from besdrake.pipeline.config import ConfigError, load_config
    from besdrake.pipeline.learn import learn, learn_scenario, stages_of
    from besdrake.task import get_task
    from besdrake.pipeline.run import RunError, RunFolder

    overrides = list(args.set)
    if args.ray:
        overrides.append(f"ray_address={args.ray}")
    if args.demonstrations:
        overrides.append(f"demonstrations.source={args.demonstrations}")
    if args.lab:
        overrides.append(f"lab={args.lab}")
    if args.task:
        overrides.append(f"task={args.task}")
    if args.robot:
        overrides.append(f"robot={args.robot}")
    if args.workers is not None:
        overrides.append(f"workers={args.workers}")
    try:
        config = load_config(args.config, quick=args.quick, overrides=overrides)
        learn_scenario(config)  # an unknown task, or a robot without what the task needs: refused now
        get_task(config["task"]).check_learn_config(config)  # a bad value is refused now, not after the refinement
        run_folder = RunFolder(args.out, config)
    except (ConfigError, RunError) as err:
        raise UserError(str(err)) from None
    if run_folder.settings_left_out:
        _check_resumable(run_folder, args.out)
        print(f"besdrake: note: {args.out} was begun by an earlier besdrake; it goes on with its own configuration, without "
              f"the settings added since: {', '.join(run_folder.settings_left_out)}", file=sys.stderr)
    config = run_folder.config
    known = [name for name, _ in stages_of(config)]
    for name in args.stage or []:
        if name not in known:
            raise UserError(f"unknown stage {name!r}; stages: {', '.join(known)}")

    bar = None
    if not args.json and sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(total=sum(_WEIGHTS.values()), desc="besdrake learn", unit="", bar_format="{l_bar}{bar}| {elapsed}<{remaining}", file=sys.stderr)

    def progress(message: str) -> None:
        if bar is not None and " done in " in message:
            bar.write(message)  # a stage's time, rollouts and the workers' busy share stay on screen
        elif bar is not None:
            bar.set_postfix_str(message[:60])
        elif not args.json:
            print(message, file=sys.stderr)

    def on_stage(name: str, record: dict) -> None:
        if bar is not None:
            bar.update(_WEIGHTS.get(name, 1))

    try:
        records = learn(run_folder, progress=progress, stages=args.stage, on_stage=on_stage, meshcat_host=args.meshcat_host)
    except _input_errors() as err:
        raise UserError(str(err)) from None
    finally:
        if bar is not None:
            bar.close()
    if args.json:
        stages = {name: rec["summary"] | {"seconds": rec["seconds"]} for name, rec in records.items()}
        if "task" in records.get("report", {}).get("summary", {}):  # a task's own pipeline: its figures first
            print(json.dumps(records["report"]["summary"] | {"stages": stages}, default=str))
        else:
            print(json.dumps(stages, default=str))
    else:
        report = run_folder.root / "report.md"
        print(f"done: {len(records)} stages in {run_folder.root}" + (f"; report: {report}" if report.is_file() else ""))
    return 0
