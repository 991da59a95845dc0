"""Tasks as plug-ins: what a skill adds to the platform, behind one small interface.

A task knows its scene (the models a scenario adds beside the robot), how one rollout of a motion plan
runs and what it measures (its outcome), what a failed rollout looks like, and which effects of the
registry apply to it. The stages know no task: the simulation's executors ask the scenario's task for a
rollout (``get_task(scenario.task).make_rollout(scenario)``) and treat it as a black box.

Built-in tasks live in ``besdrake/tasks/<name>/task.py`` and are imported on first use; a task of your own
is a module with a :class:`Task` subclass decorated with :func:`register_task`, loaded with ``--plugin``
(like effects).
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from pathlib import Path
from typing import Any, ClassVar

TASKS_DIR = Path(__file__).resolve().parent / "tasks"
#: The task a stage uses where none is named (e.g. a refinement problem without ``task=``, an old run record).
DEFAULT_TASK = "throwing"
_REGISTRY: dict[str, type["Task"]] = {}


class TaskError(ValueError):
    """An unknown task, or a task module that does not define what it must."""


class Task(ABC):
    """One skill. Subclasses set ``name``, ``description``, ``default_scenario`` and ``effects`` and implement
    :meth:`make_rollout` and :meth:`failed_outcome`."""

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    #: The scenario (built-in name or YAML path) the task runs in when none is given; it names the robot.
    default_scenario: ClassVar[str] = ""
    #: Names of the registry's effects that act on this task's rollouts.
    effects: ClassVar[tuple[str, ...]] = ()
    #: Markers of the manipulated object in the task's demonstrations (mocap marker names): the segment classifier's
    #: ``markers="auto"`` adds them to the hand's features where they are visible throughout.
    object_markers: ClassVar[tuple[str, ...]] = ()
    #: The built-in lab (``diagrams/labs/<name>.yaml``) the task's commands open when none is given; "" for none.
    default_lab: ClassVar[str] = ""
    #: The task's own ``besdrake learn`` configuration (YAML; its ``quick:`` section is the ``--quick`` profile), or
    #: None when the task runs the pipeline's default stages (:mod:`besdrake.pipeline.learn`) and configuration.
    learn_config: ClassVar[Path | None] = None

    def check_learn_config(self, config: dict[str, Any]) -> None:
        """Raise a ``ValueError`` (e.g. :class:`~besdrake.pipeline.config.ConfigError`) naming a bad value of the
        task's ``besdrake learn`` configuration, before any stage runs (a late stage must not fail on it)."""

    def learn_stages(self) -> list | None:
        """The task's ``besdrake learn`` stages ``[(name, fn(ctx, out_dir) -> summary)]``, or None for the pipeline's
        default stages. The last stage's summary is the run's JSON line."""
        return None

    @abstractmethod
    def make_rollout(self, scenario, meshcat=None) -> Any:
        """A rollout black box for ``scenario``: ``rollout(plan, effects=None, limits="flag") -> outcome``."""

    @abstractmethod
    def failed_outcome(self, message: str) -> Any:
        """The outcome of a rollout that could not run (flagged as failed, ``message`` says why)."""

    def scene(self) -> Any:
        """The scene the task adds to the simulation's Diagram beside the robot (its objects and fixtures), or None
        (the robot alone): an object with ``add_models(plant, parser, scenario)`` and ``finish(plant, scene_graph,
        arm) -> handles`` (see :mod:`besdrake.sim.diagram`). A task that builds its own Diagram needs none."""
        return None

    def default_plan(self, rollout, **shape) -> Any:
        """A motion plan that performs the task in ``rollout``'s scene (what ``besdrake simulate`` runs when no
        plan is given); ``shape``: the command line's ``amplitude``/``yaw``, for tasks whose default plan takes them."""
        raise TaskError(f"the task {self.name!r} has no default plan: give --plan FILE")

    @staticmethod
    def _no_shape(task: str, shape: dict) -> None:
        if shape:
            raise TaskError(f"--amplitude and --yaw shape a task's default plan; the {task} task takes --plan FILE")

    def make_lab(self, config, seed: int | None = None) -> Any:
        """The task's virtual lab (a :class:`~besdrake.transfer.lab.Lab`) from a lab config: a YAML path, a built-in
        lab's name or a mapping (see :func:`besdrake.transfer.lab_config.open_lab`, which picks the task from the
        config's scenario); ``seed`` replaces the config's noise seed. Raises ``LabConfigError`` naming the field."""
        raise TaskError(f"the task {self.name!r} has no virtual lab")

    def measurement_type(self) -> type:
        """The :class:`~besdrake.transfer.measurement.Measurement` (sub)class the task's labs return and its logs
        hold (read back by :mod:`besdrake.transfer.log` from the log's ``task``)."""
        from besdrake.transfer.measurement import Measurement

        return Measurement

    def summary(self, outcome) -> dict[str, Any]:
        """A JSON-ready summary of one ``outcome`` (its ``summary()`` or ``to_dict()`` by default)."""
        return outcome.summary() if hasattr(outcome, "summary") else outcome.to_dict()

    def record_replay(self, rollout, plan, outcome, meshcat, fps: float) -> None:
        """Pose ``rollout``'s Diagram frame by frame (every ``1/fps`` s) as ``plan`` ran in ``outcome`` and record the
        frames into ``meshcat`` (``besdrake record``, ``simulate --record``: :func:`besdrake.sim.record.record_html`)."""
        raise TaskError(f"the task {self.name!r} draws no replay")

    def reward(self, **settings) -> Any:
        """The task's reward for policy search with ``settings`` (e.g. ``target``): a callable
        ``reward(plan, outcome, limits) -> RewardBreakdown`` (:mod:`besdrake.search.refinement.records`) with ``target``,
        ``penalty(plan, limits)`` (m) and ``to_dict()``, what :class:`~besdrake.search.refinement.RefinementProblem`
        maximises."""
        raise TaskError(f"the task {self.name!r} defines no reward for refinement")

    def reward_from_dict(self, settings: dict[str, Any]) -> Any:
        """The reward written by its ``to_dict()`` (a refinement run's record)."""
        return self.reward(**settings)

    def behaviour_descriptor(self, plan, outcome) -> Any:
        """The behaviour features (a 1-D float array, the same length for every rollout) of ``plan`` as simulated in
        ``outcome``: what the Transferability surrogate (:mod:`besdrake.transfer.transferability`) learns the
        sim-to-lab disparity from."""
        raise TaskError(f"the task {self.name!r} describes no behaviour (Transferability needs behaviour_descriptor)")

    def scatter_effects(self, scenario, sd: float) -> tuple[list, Any]:
        """The lab's trial-to-trial scatter of the task's setup (``sd``, m per axis; e.g. where an object is put) as
        ``(effects, weights)``: K effect mappings for one rollout each, the first None (the scenario's own setup), and
        the K weights (summing to 1) of a quadrature over that scatter (the Transferability Approach's expected target
        distance). Default: no scatter modelled, ``([None], [1.0])``."""
        import numpy as np

        return [None], np.ones(1)

    def diagnosis_model(self) -> Any:
        """The task's trials as the diagnosis reads them (:class:`~besdrake.diagnosis.trials.TrialModel`: the observables
        of a trial, how a measurement and a simulated outcome are read alike, the designed diagnosis experiments), what
        ``besdrake diagnose`` needs; :class:`TaskError` when the task has none."""
        raise TaskError(f"the task {self.name!r} has no diagnosis (Task.diagnosis_model)")

    def check_robot(self, robot) -> None:
        """Raise :class:`~besdrake.robot.RobotError` when ``robot`` lacks what the task needs (e.g. a scoop)."""

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "description": self.description, "default_scenario": self.default_scenario,
                "effects": list(self.effects), "default_lab": self.default_lab}


def register_task(cls: type[Task]) -> type[Task]:
    """Class decorator: make ``cls`` available by ``cls.name``."""
    if not (isinstance(cls, type) and issubclass(cls, Task)) or not cls.name:
        raise TaskError(f"{cls!r} is not a Task subclass with a name")
    _REGISTRY[cls.name] = cls
    return cls


def load_task_effects() -> None:
    """Import every built-in task's effects module (``besdrake/tasks/<name>/effects.py``, in name order): their
    ``@register_effect`` classes join the registry (:mod:`besdrake.sim.effects` calls this before it is first read)."""
    for path in sorted(TASKS_DIR.glob("*/effects.py")):
        importlib.import_module(f"besdrake.tasks.{path.parent.name}.effects")


def effects_for(task: str) -> list[str]:
    """The registry's effects (in application order) that act on ``task``'s rollouts (:func:`effects_not_for` names
    the others): the default candidates of its diagnosis."""
    from besdrake.sim.effects import list_effects

    names = list_effects()
    other = set(effects_not_for(task, names))
    return [n for n in names if n not in other]


def effects_not_for(task: str, names) -> list[str]:
    """Those of ``names`` that do not act on ``task``'s rollouts: an effect acts on them when the task lists it
    (:attr:`Task.effects`), when it is a user's plugin effect that no other task lists, or when it is a robot effect of
    :mod:`besdrake.sim.effects` and the task lists none (it declares nothing). So another task's own effects (e.g. the
    pick-and-place box's mass for throwing) and the robot effects a declaring task does not list (its rollout does not
    apply them) are left out. The one rule behind :func:`effects_for`, the rollouts' refusals and the diagnosis' check
    of its candidates."""
    own = set(get_task(task).effects)
    others = {e for name in known_tasks() if name != task for e in get_task(name).effects}

    def acts(n: str) -> bool:
        origin = effect_origin(n)
        return n in own or (origin is None and n not in others) or (origin == "" and not own)

    return sorted(n for n in names if not acts(n))


def effect_origin(name: str) -> str | None:
    """Who registered the effect ``name``: a built-in task's name (its ``besdrake/tasks/<task>/effects.py``), "" for the
    robot effects of :mod:`besdrake.sim.effects`, None for anything else (a user's plugin)."""
    from besdrake.sim.effects import get_effect

    module = type(get_effect(name)).__module__
    if module == "besdrake.sim.effects":
        return ""
    parts = module.split(".")
    return parts[2] if len(parts) >= 4 and parts[:2] == ["besdrake", "tasks"] else None


def object_markers() -> tuple[str, ...]:
    """The object markers of every known task (:attr:`Task.object_markers`), in task-name order, without repeats."""
    out: list[str] = []
    for name in known_tasks():
        out += [m for m in get_task(name).object_markers if m not in out]
    return tuple(out)


def known_tasks() -> list[str]:
    """Built-in task folders and registered tasks."""
    builtin = {p.parent.name for p in TASKS_DIR.glob("*/task.py")}
    return sorted(builtin | set(_REGISTRY))


def scenario_scatter(scenario, sd: float) -> tuple[list, Any] | None:
    """The lab's setup scatter of ``sd`` (m per axis) in ``scenario`` as its task's quadrature
    (:meth:`Task.scatter_effects`: effects, the nominal first as None, and weights); None for ``sd`` 0."""
    return get_task(scenario.task).scatter_effects(scenario, sd) if sd > 0 else None


def get_task(name: str) -> Task:
    """The task called ``name`` (a built-in one is imported on first use); :class:`TaskError` if unknown."""
    if name not in _REGISTRY and (TASKS_DIR / str(name) / "task.py").is_file():
        importlib.import_module(f"besdrake.tasks.{name}.task")
    if name not in _REGISTRY:
        raise TaskError(f"unknown task {name!r} (known: {known_tasks()})")
    return _REGISTRY[name]()
