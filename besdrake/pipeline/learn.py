"""``besdrake learn``: from demonstrations to a template pool, stage after stage, in a resumable run folder.

The stages are the task's (:meth:`besdrake.task.Task.learn_stages`: ``[(name, fn(ctx, out_dir) -> summary)]``, each
writing into ``RUN/NN_name/``; e.g. the default task's label, segment, imitate, refine, transfer, diagnose,
transfer_refined, template, pool and report, paper Table 1 and Figure 1), its configuration the task's
(:mod:`besdrake.pipeline.config`). This module runs them: a stage that finished is skipped on a rerun with the same
folder; a stage named ``diagnose`` is left out when the configuration's ``diagnosis.enabled`` is false.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from besdrake._io import write_text as _atomic_write_text
from besdrake.pipeline.run import RunFolder


@dataclass
class Context:
    """What the stages share: the run folder, the configuration and lazily built tools."""

    run: RunFolder
    config: dict[str, Any]
    progress: Callable[[str], None] = print
    cache: dict[str, Any] = field(default_factory=dict)
    #: Interface the meshcat server of the report's replays listens on (a run option, not configuration).
    meshcat_host: str = "localhost"

    def robot(self, scenario: str | None = None):
        """The robot of ``scenario`` (default: the configured one), from its robot file."""
        from besdrake.sim.scenario import load_scenario

        return load_scenario(scenario or self.config["scenario"]).robot

    def mapping(self):
        if "mapping" not in self.cache:
            from besdrake.embodiment import EmbodimentMapping

            self.cache["mapping"] = EmbodimentMapping(self.robot())
        return self.cache["mapping"]


# --------------------------------------------------------------------------------------------
# what every task's stages share
# --------------------------------------------------------------------------------------------
def stage_executor(ctx: Context, scenario: str):
    """The rollout backend the configuration asks for: Ray, a process pool, or this process."""
    from besdrake.sim import make_executor

    workers = int(ctx.config["workers"])
    if ctx.config.get("ray_address"):
        ex = make_executor("ray", workers=workers, scenario=scenario, address=ctx.config["ray_address"])
    elif workers > 1:
        ex = make_executor("process", workers=workers, scenario=scenario)
    else:
        ex = make_executor("serial", scenario=scenario)
    ctx.cache.setdefault("stage_executors", []).append(ex)  # their stats: the workers' busy share per stage
    return ex


def executor_stats(ctx: Context) -> dict[str, Any] | None:
    """The stage's rollouts, wall and busy seconds summed over its executors (None if it simulated nothing)."""
    from besdrake.sim.executors import ExecutorStats

    total = ExecutorStats()
    for e in ctx.cache.pop("stage_executors", []):
        total.add(e.stats)
    return total.to_dict() if total.rollouts else None


def busy_line(stats: dict[str, Any]) -> str:
    """The stage's executor figures in one parenthesis: rollouts, their rate, the workers' busy share while simulating
    and over the whole stage, and the batches' width (rollouts a pool of any size could run at once)."""
    return (f" ({stats['rollouts']} rollouts, {stats['rollouts_per_s']}/s, workers busy {stats['busy_share']:.0%} while simulating, "
            f"{stats['stage_busy_share']:.0%} of the stage; {stats['batches']} batches, width {stats['width_mean']:.1f} mean, "
            f"{stats['width_max']} max: a 16-worker pool {stats['fill_16_workers']:.0%} busy at best, 64 workers {stats['fill_64_workers']:.0%})")


def fmt_time(seconds: float | None) -> str:
    """``seconds`` as "12.3 s" or "2:05.0 min" ("-" for None)."""
    if seconds is None:
        return "-"
    return f"{int(seconds // 60)}:{seconds % 60:04.1f} min" if seconds >= 60 else f"{seconds:.1f} s"



def learn_scenario(config: dict[str, Any]):
    """The scenario the run simulates: ``config["scenario"]``, on ``config["robot"]`` when one is given.
    :class:`~besdrake.pipeline.config.ConfigError` when the task is unknown or not the scenario's, or the robot
    cannot do the task."""
    from besdrake.pipeline.config import ConfigError
    from besdrake.robot import RobotError
    from besdrake.sim.scenario import ScenarioError, load_scenario
    from besdrake.task import TaskError, get_task

    name = str(config.get("task", ""))
    if not isinstance(config.get("scenario"), str) or not isinstance(config.get("robot") or "", str):
        raise ConfigError(f"scenario and robot must be names or YAML paths, got {config.get('scenario')!r}, {config.get('robot')!r}")
    try:
        task = get_task(name)
        scenario = load_scenario(config["scenario"])
        if config.get("robot"):
            scenario = scenario.with_robot(config["robot"])
        task.check_robot(scenario.robot)
    except (TaskError, ScenarioError, RobotError) as err:
        raise ConfigError(str(err)) from None
    if task.learn_stages() is None:
        raise ConfigError(f"the task {name!r} has no besdrake learn stages (Task.learn_stages)")
    if scenario.task != name:
        raise ConfigError(f"scenario {scenario.name!r} simulates the task {scenario.task!r}, not {name!r}")
    return scenario


def run_scenario(config: dict[str, Any], root: Path) -> str:
    """The scenario of :func:`learn_scenario` as the stages name it: the configured one, or, on another robot,
    ``root/scenario.yaml`` (written once; a resumed run finds the same file)."""
    import yaml

    scenario = learn_scenario(config)
    if not config.get("robot"):
        return str(config["scenario"])
    path = Path(root) / "scenario.yaml"
    text = yaml.safe_dump(scenario.to_dict(), sort_keys=False)
    if not path.is_file() or path.read_text() != text:
        _atomic_write_text(path, text)
    return str(path)


def stages_of(config: dict[str, Any]) -> list[tuple[str, Callable[[Context, Path], dict[str, Any]]]]:
    """The stages of ``config``'s task (:meth:`besdrake.task.Task.learn_stages`); :class:`ConfigError` for a task
    without any."""
    from besdrake.pipeline.config import ConfigError
    from besdrake.task import DEFAULT_TASK, get_task

    own = get_task(str(config.get("task") or DEFAULT_TASK)).learn_stages()
    if own is None:
        raise ConfigError(f"the task {config.get('task')!r} has no besdrake learn stages (Task.learn_stages)")
    return own


def learn(
    run: RunFolder,
    progress: Callable[[str], None] = print,
    stages: list[str] | None = None,
    on_stage: Callable[[str, dict[str, Any]], None] | None = None,
    meshcat_host: str = "localhost",
) -> dict[str, Any]:
    """Run every stage not yet done (or only ``stages``); returns each stage's record.

    ``progress`` receives messages; ``on_stage(name, record)`` is called after each stage, run or skipped."""
    ctx = Context(run, dict(run.config, scenario=run_scenario(run.config, run.root)), progress, meshcat_host=meshcat_host)
    records = {}
    all_stages = stages_of(run.config)
    for i, (name, fn) in enumerate(all_stages, 1):
        if name == "diagnose" and not run.config.get("diagnosis", {}).get("enabled", True):
            continue
        if stages is not None and name not in stages:
            continue
        rec = run.done(i, name)
        if rec is None:
            progress(f"[{i}/{len(all_stages)}] {name} ...")
            t0 = time.perf_counter()
            summary = fn(ctx, run.stage_dir(i, name))
            stats = executor_stats(ctx)
            seconds = time.perf_counter() - t0
            if stats is not None:
                stats["stage_busy_share"] = round(min(1.0, stats["busy_s"] / (seconds * stats["workers"])), 3)
                summary = summary | {"executor": stats}
            rec = run.mark_done(i, name, summary, seconds)
            busy = "" if stats is None else busy_line(stats)
            progress(f"[{i}/{len(all_stages)}] {name} done in {fmt_time(rec['seconds'])}{busy}")
        else:
            progress(f"[{i}/{len(all_stages)}] {name}: done earlier, skipped")
        records[name] = rec
        if on_stage is not None:
            on_stage(name, rec)
    return records
