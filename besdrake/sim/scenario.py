"""Scenarios as data: which models, base pose, time step, contact model, controller and effects a
simulation has. A scenario is a YAML file in ``diagrams/``; ``load_scenario("nominal")`` resolves to
``diagrams/nominal.yaml``. Every field is validated here so that a mistake in a file is reported
by name (:class:`ScenarioError`) before Drake sees it.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from besdrake.robot import MODELS_DIR, PACKAGE_NAME, Robot, RobotError, load_robot

DIAGRAMS_DIR: Path = Path(__file__).resolve().parents[1] / "diagrams"

CONTACT_APPROXIMATIONS = ("sap", "lagged", "similar")
CONTROLLERS = ("joint_pd",)


class ScenarioError(ValueError):
    """A scenario file is missing, unreadable or has an invalid field."""


@dataclass
class BasePose:
    """Pose of the robot's base link in the world: position in m, yaw in rad."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.5
    yaw: float = 0.0


@dataclass
class ControllerConfig:
    """Joint PD servo: proportional gains ``kp`` (N m/rad) and damping ``kd`` (N m s/rad), one per arm joint
    (the robot file's gains where the scenario gives none)."""

    type: str = "joint_pd"
    kp: list[float] = field(default_factory=list)
    kd: list[float] = field(default_factory=list)


@dataclass
class ReleaseConfig:
    """How a task's rollout decides that a released object has left the robot's tool for good (tasks that release
    one read it; the scenario's ``release`` section).

    ``check_interval``: the simulator advances in chunks of this length (s) and checks the object between
    chunks; ``margin``: clearance (m) that the object's predicted free flight must keep from the tool (moving
    along the plan) for the object to count as gone (see the task's rollout); ``min_speed``: an object
    that leaves with less speed (m/s) fell out rather than being released on purpose (flag ``dropped_early``);
    ``tail``: time (s) simulated after the end of the plan before ``never_released`` is declared.
    """

    check_interval: float = 0.02
    margin: float = 0.002
    min_speed: float = 1.0
    tail: float = 0.3


@dataclass
class Scenario:
    """A validated simulation scenario (see ``diagrams/nominal.yaml`` for the meaning of each field)."""

    name: str
    time_step: float
    contact_approximation: str
    robot: Robot
    task: str
    models: dict[str, str]
    base: BasePose
    controller: ControllerConfig
    release: ReleaseConfig
    effects: dict[str, dict[str, float]] = field(default_factory=dict)
    description: str = ""
    path: Path | None = None

    def with_overrides(self, **changes: Any) -> "Scenario":
        """A copy with some top-level fields replaced (e.g. ``time_step=0.001`` for a reference run)."""
        new = copy.deepcopy(self)
        for key, value in changes.items():
            if not hasattr(new, key):
                raise ScenarioError(f"scenario has no field {key!r}")
            setattr(new, key, value)
        return new

    def with_robot(self, robot: Robot | str | Path) -> "Scenario":
        """A copy on another robot (a :class:`Robot`, built-in name or robot file), with that robot's servo gains."""
        try:
            robot = load_robot(robot)
        except RobotError as err:
            raise ScenarioError(str(err)) from err
        new = self.with_overrides(robot=robot)
        new.controller = ControllerConfig(self.controller.type, [float(x) for x in robot.kp], [float(x) for x in robot.kd])
        return new

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "description": self.description,
            "time_step": self.time_step,
            "contact": {"approximation": self.contact_approximation},
            "robot": self.robot.reference,
            "task": self.task,
            "models": dict(self.models),
            "base": vars(self.base).copy(),
            "controller": {"type": self.controller.type, "kp": list(self.controller.kp), "kd": list(self.controller.kd)},
            "release": vars(self.release).copy(),
            "effects": copy.deepcopy(self.effects),
        }


def _resolve(path_or_name: str | Path) -> Path:
    p = Path(path_or_name)
    if p.suffix in (".yaml", ".yml") or p.exists() or "/" in str(path_or_name):
        return p
    return DIAGRAMS_DIR / f"{path_or_name}.yaml"


def _number(section: str, key: str, value: Any, low: float | None = None, high: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ScenarioError(f"scenario field {section}.{key} must be a number, got {value!r}")
    v = float(value)
    if not np.isfinite(v):
        raise ScenarioError(f"scenario field {section}.{key} must be finite, got {value!r}")
    if (low is not None and v < low) or (high is not None and v > high):
        raise ScenarioError(f"scenario field {section}.{key}={v:g} is outside [{low}, {high}]")
    return v


def _section(data: dict, key: str, required: bool = True) -> dict:
    if key not in data:
        if required:
            raise ScenarioError(f"scenario is missing the section {key!r}")
        return {}
    sec = data[key]
    if sec is None:
        return {}
    if not isinstance(sec, dict):
        raise ScenarioError(f"scenario section {key!r} must be a mapping, got {type(sec).__name__}")
    return sec


def _check_keys(section: str, sec: dict, allowed: set[str]) -> None:
    unknown = set(sec) - allowed
    if unknown:
        raise ScenarioError(f"scenario section {section!r} has unknown key(s) {sorted(unknown)}; allowed: {sorted(allowed)}")


def resolve_model_uri(uri: str) -> Path:
    """Path of a model given as ``package://besdrake_models/...`` or a path relative to ``besdrake/models/``."""
    prefix = f"package://{PACKAGE_NAME}/"
    if uri.startswith(prefix):
        return MODELS_DIR / uri[len(prefix):]
    if uri.startswith("package://"):
        raise ScenarioError(f"model {uri!r} is in an unknown package (only {PACKAGE_NAME} is known)")
    p = Path(uri)
    return p if p.is_absolute() else MODELS_DIR / p


def _robot(data: dict, path: Path | None) -> Robot:
    """The scenario's robot: a built-in name or a robot file (a relative path is read from the scenario's folder)."""
    if "robot" not in data:
        raise ScenarioError(f"scenario{f' ({path})' if path else ''} is missing 'robot' (a robot name or robot YAML path)")
    value = str(data["robot"])
    candidate = (path.parent / value) if path is not None and not Path(value).is_absolute() else Path(value)
    try:
        return load_robot(candidate if candidate.is_file() else value)
    except RobotError as err:
        raise ScenarioError(f"scenario robot: {err}") from err


def scenario_from_dict(data: Any, path: Path | None = None) -> Scenario:
    """Validate a parsed YAML mapping into a :class:`Scenario` (:class:`ScenarioError` naming the field)."""
    where = f" ({path})" if path else ""
    if not isinstance(data, dict):
        raise ScenarioError(f"scenario{where} must be a YAML mapping, got {type(data).__name__}")
    _check_keys("<top>", data, {"name", "description", "time_step", "contact", "robot", "task", "models", "base", "controller", "release", "effects"})
    name = str(data.get("name") or (path.stem if path else "unnamed"))
    if "time_step" not in data:
        raise ScenarioError(f"scenario{where} is missing time_step")
    time_step = _number("<top>", "time_step", data["time_step"], 1e-5, 0.02)
    approx = _contact(data)
    robot = _robot(data, path)
    models = _models(data)
    base = _base(data)
    controller = _controller(_section(data, "controller", required=False), robot)
    release = _release(data, time_step)
    effects = _effects(data, where)
    return Scenario(
        name=name,
        description=str(data.get("description", "")),
        time_step=time_step,
        contact_approximation=approx,
        robot=robot,
        task=_task(data, where),
        models=models,
        base=base,
        controller=controller,
        release=release,
        effects=effects,
        path=path,
    )


def _contact(data: dict) -> str:
    """The contact approximation (TAMSI refused: it ignores the joint PD gains)."""
    contact = _section(data, "contact", required=False)
    _check_keys("contact", contact, {"approximation"})
    approx = str(contact.get("approximation", "lagged"))
    if approx not in CONTACT_APPROXIMATIONS:
        extra = " (TAMSI ignores the joint PD gains: the arm falls)" if approx == "tamsi" else ""
        raise ScenarioError(f"contact.approximation {approx!r} is not one of {CONTACT_APPROXIMATIONS}{extra}")
    return approx


def _models(data: dict) -> dict[str, str]:
    """The scene's model files by key; each must resolve to an existing file."""
    models = _section(data, "models", required=False)
    for key in models:
        file = resolve_model_uri(str(models[key]))
        if not file.is_file():
            raise ScenarioError(f"model file for {key!r} not found: {models[key]} -> {file}")
    return {k: str(v) for k, v in models.items()}


def _base(data: dict) -> BasePose:
    base_sec = _section(data, "base", required=False)
    _check_keys("base", base_sec, {"x", "y", "z", "yaw"})
    return BasePose(
        x=_number("base", "x", base_sec.get("x", 0.0), -5, 5),
        y=_number("base", "y", base_sec.get("y", 0.0), -5, 5),
        z=_number("base", "z", base_sec.get("z", 0.5), 0.0, 3.0),
        yaw=_number("base", "yaw", base_sec.get("yaw", 0.0), -np.pi, np.pi),
    )


def _release(data: dict, time_step: float) -> ReleaseConfig:
    rel_sec = _section(data, "release", required=False)
    _check_keys("release", rel_sec, {"check_interval", "margin", "min_speed", "tail"})
    d = ReleaseConfig()
    return ReleaseConfig(
        check_interval=_number("release", "check_interval", rel_sec.get("check_interval", d.check_interval), time_step, 1.0),
        margin=_number("release", "margin", rel_sec.get("margin", d.margin), 0.0, 0.5),
        min_speed=_number("release", "min_speed", rel_sec.get("min_speed", d.min_speed), 0.0, 20.0),
        tail=_number("release", "tail", rel_sec.get("tail", d.tail), 0.0, 5.0),
    )


def _effects(data: dict, where: str) -> dict:
    effects = _section(data, "effects", required=False)
    from besdrake.sim.effects import normalize_effects  # late import: effects may be user-registered

    try:
        return normalize_effects(effects)
    except ValueError as err:
        raise ScenarioError(f"scenario{where} effects: {err}") from err


def _task(data: dict, where: str) -> str:
    """The scenario's task: a known task's name (its scene and rollout, see :mod:`besdrake.task`)."""
    from besdrake.task import TaskError, get_task

    if "task" not in data:
        raise ScenarioError(f"scenario{where} is missing 'task' (the skill it simulates, a task name)")
    try:
        return get_task(str(data["task"])).name
    except TaskError as err:
        raise ScenarioError(f"scenario{where} task: {err}") from err


def _controller(sec: dict, robot: Robot) -> ControllerConfig:
    """Joint PD gains: the scenario's where given (a number or one per arm joint), else the robot file's."""
    _check_keys("controller", sec, {"type", "kp", "kd"})
    ctype = str(sec.get("type", "joint_pd"))
    if ctype not in CONTROLLERS:
        raise ScenarioError(f"controller.type {ctype!r} is not one of {CONTROLLERS}")
    n = robot.n_joints
    gains = {}
    for key, default in (("kp", robot.kp), ("kd", robot.kd)):
        v = sec.get(key, [float(x) for x in default])
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            v = [v] * n
        if not isinstance(v, list) or len(v) != n:
            raise ScenarioError(f"controller.{key} must be a number or a list of {n} numbers, got {v!r}")
        gains[key] = [_number("controller", f"{key}[{i}]", x, 0.0, 1e6) for i, x in enumerate(v)]
    return ControllerConfig(type=ctype, kp=gains["kp"], kd=gains["kd"])


def load_scenario(path_or_name: str | Path = "nominal") -> Scenario:
    """Load and validate a scenario: a YAML path, or a name in ``diagrams/`` (``"nominal"``)."""
    if isinstance(path_or_name, Scenario):
        return path_or_name
    path = _resolve(path_or_name)
    if not path.is_file():
        known = sorted(p.stem for p in DIAGRAMS_DIR.glob("*.yaml"))
        raise ScenarioError(f"scenario file not found: {path} (known scenarios: {known})")
    try:
        data = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as err:
        raise ScenarioError(f"scenario file {path} is not valid YAML: {err}") from err
    return scenario_from_dict(data, path)
