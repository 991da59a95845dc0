"""Robots as data: a :class:`Robot` is read from a YAML description file and handed to every stage.

A robot file names the model file(s) and the packages they need, the base link that is welded to the
world, the arm's joints with their position / velocity / acceleration / effort limits (and where each
limit comes from), the tool frame, the end effector (a tool without joints, or a gripper with its
joints and open / closed positions), a home pose, the joint servo gains, what the safety gate needs
(longest plan, control period, start tolerance) and the hints the embodiment mapping reads (which
demonstrated body part drives the tool, which tool axis matches the palm; for a full tool pose, the tool
frame's orientation in the hand plate frame, ``mapping.hand_to_tool_rpy``).

Built-in robots live beside their model files, ``besdrake/models/<name>/robot.yaml``, and are found by
name (``load_robot("compi")``); any other file is found by path. Relative model and package paths in a
file are read from the file's folder. Every field is checked when the file is read, the names against
the model itself, so a mistake is reported as one :class:`RobotError` naming the file and the field.
"""

from __future__ import annotations

import functools
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

#: Folder with the built-in models and robot files, and ``package.xml`` (package ``besdrake_models``).
MODELS_DIR: Path = Path(__file__).resolve().parent / "models"
PACKAGE_NAME = "besdrake_models"
END_EFFECTOR_TYPES = ("fixed", "gripper")
_TOP_KEYS = {"name", "description", "model", "base_link", "joints", "tool_frame", "end_effector", "home",
             "controller", "safety", "mapping", "sources"}


class RobotError(ValueError):
    """A robot description is missing, unreadable or has an invalid field (the message names both)."""


@dataclass(frozen=True, eq=False)
class JointLimits:
    """Limits of ``names`` (n joints): ``position`` (n, 2) rad, ``velocity`` (n,) rad/s,
    ``acceleration`` (n,) rad/s^2. The arrays are read-only."""

    names: tuple[str, ...]
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.names)
        for name, shape in (("position", (n, 2)), ("velocity", (n,)), ("acceleration", (n,))):
            arr = np.array(getattr(self, name), dtype=float)
            if arr.shape != shape or not np.all(np.isfinite(arr)):
                raise ValueError(f"JointLimits.{name} must be finite with shape {shape}, got {arr.shape}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if np.any(self.position[:, 0] >= self.position[:, 1]):
            raise ValueError("JointLimits.position: every lower limit must be below its upper limit")
        if np.any(self.velocity <= 0) or np.any(self.acceleration <= 0):
            raise ValueError("JointLimits: velocity and acceleration limits must be positive")

    @property
    def n_joints(self) -> int:
        return len(self.names)

    def within(self, q: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Boolean mask: which entries of ``q`` (..., n) lie within the position limits less ``margin``."""
        q = np.asarray(q, dtype=float)
        return (q >= self.position[:, 0] + margin) & (q <= self.position[:, 1] - margin)

    def clip(self, q: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """``q`` clipped into the position limits less ``margin``."""
        return np.clip(q, self.position[:, 0] + margin, self.position[:, 1] - margin)


@dataclass(frozen=True, eq=False)
class Gripper:
    """A gripper's joints, their actuators, open and closed positions (m or rad) and servo gains; ``coupled``: joints
    that the model couples 1:1 to the first gripper joint (a URDF ``<mimic>``, a coupler constraint under SAP), not
    actuated themselves (e.g. the second finger of a belt-driven parallel gripper)."""

    joints: tuple[str, ...]
    actuators: tuple[str | None, ...]
    open: np.ndarray
    closed: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    effort: np.ndarray
    coupled: tuple[str, ...] = ()


@dataclass(frozen=True, eq=False)
class EndEffector:
    """The tool: ``type`` "fixed" (no joints, e.g. a scoop) or "gripper"; its ``body``; task parameters
    of the tool in ``params`` (e.g. a scoop's geometry), read by the task that uses them."""

    type: str
    body: str
    gripper: Gripper | None = None
    params: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class SafetyDefaults:
    """What the safety gate needs beyond the joint limits: the longest plan (s), the closest knots (s; closer
    ones are no motion a controller can follow) and how far (rad) a plan may start from the current pose."""

    max_plan_duration: float = 30.0
    min_knot_spacing: float = 1e-4
    start_tolerance: float = 0.05


@dataclass(frozen=True, eq=False)
class Robot:
    """A validated robot description (see ``besdrake/models/compi/robot.yaml`` for each field)."""

    name: str
    description: str
    path: Path | None
    model: Path
    packages: dict[str, Path]
    base_link: str
    limits: JointLimits
    actuators: tuple[str | None, ...]
    effort: np.ndarray
    tool_frame: str
    end_effector: EndEffector
    home: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    safety: SafetyDefaults
    mapping: dict[str, Any]
    sources: dict[str, str]

    @property
    def reference(self) -> str:
        """How a file refers to this robot: its name when built in, else its file's path."""
        builtin = MODELS_DIR / self.name / "robot.yaml"
        return self.name if self.path is not None and self.path == builtin.resolve() else str(self.path or self.name)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.limits.names

    @property
    def n_joints(self) -> int:
        return self.limits.n_joints

    @property
    def position_limits(self) -> np.ndarray:
        return self.limits.position

    @property
    def velocity_limits(self) -> np.ndarray:
        return self.limits.velocity

    @property
    def acceleration_limits(self) -> np.ndarray:
        return self.limits.acceleration

    def add_packages(self, package_map) -> None:
        """Make the model's packages (and ``besdrake_models``) known to a Drake ``PackageMap``."""
        add_package(package_map)
        for name, folder in self.packages.items():
            if not package_map.Contains(name):  # the file's name, as the model's URIs spell it (a package.xml may
                package_map.Add(name, str(folder))  # name it otherwise: example-robot-data's says example_robot_descriptions)

    def add_model(self, plant, parser=None):
        """Parse the robot into ``plant`` (before ``Finalize``); returns its model instance. Joints whose
        actuator the file leaves out (``actuator: null``; e.g. URDFs without transmissions) get one here,
        named ``<joint>_motor``, with the file's effort limit."""
        from pydrake.multibody.parsing import Parser

        parser = parser or Parser(plant)
        self.add_packages(parser.package_map())
        instances = parser.AddModels(str(self.model))
        instance = instances[0]
        for joint_name, actuator, effort in zip(self._all_joints(), self._all_actuators(), self._all_efforts()):
            if actuator is None:
                joint = plant.GetJointByName(joint_name, instance)
                plant.AddJointActuator(f"{joint_name}_motor", joint, float(effort) if np.isfinite(effort) else np.inf)
        return instance

    def actuator_name(self, joint: str) -> str:
        """Name of the actuator that drives ``joint`` (arm or gripper)."""
        for name, act in zip(self._all_joints(), self._all_actuators()):
            if name == joint:
                return act or f"{name}_motor"
        raise KeyError(f"robot {self.name!r} has no joint {joint!r}")

    def _all_joints(self) -> tuple[str, ...]:
        g = self.end_effector.gripper
        return self.joint_names + (g.joints if g else ())

    def _all_actuators(self) -> tuple[str | None, ...]:
        g = self.end_effector.gripper
        return self.actuators + (g.actuators if g else ())

    def _all_efforts(self) -> np.ndarray:
        g = self.end_effector.gripper
        return np.concatenate([self.effort, g.effort if g else []])

    def describe(self) -> dict[str, Any]:
        """A JSON-ready summary (name, file, joints and limits, tool, end effector)."""
        return {
            "name": self.name,
            "file": str(self.path) if self.path else None,
            "model": str(self.model),
            "joints": list(self.joint_names),
            "position_limits_rad": self.position_limits.tolist(),
            "velocity_limits_rad_s": self.velocity_limits.tolist(),
            "acceleration_limits_rad_s2": self.acceleration_limits.tolist(),
            "tool_frame": self.tool_frame,
            "end_effector": {"type": self.end_effector.type, "body": self.end_effector.body,
                             "gripper_joints": list(self.end_effector.gripper.joints) if self.end_effector.gripper else []},
        }


def package_xml_path() -> Path:
    """Path of ``besdrake/models/package.xml`` that makes ``package://besdrake_models/...`` resolve."""
    path = MODELS_DIR / "package.xml"
    if not path.is_file():
        raise FileNotFoundError(f"model package file missing: {path}")
    return path


def add_package(package_map) -> None:
    """Add the ``besdrake_models`` package to a Drake ``PackageMap`` (idempotent)."""
    if not package_map.Contains(PACKAGE_NAME):
        package_map.AddPackageXml(str(package_xml_path()))


def known_robots() -> list[str]:
    """Names of the built-in robots (folders of ``besdrake/models`` with a ``robot.yaml``)."""
    return sorted(p.parent.name for p in MODELS_DIR.glob("*/robot.yaml"))


def robot_file(name_or_path: str | Path) -> Path:
    """The robot file a name (``"compi"``) or a path stands for; :class:`RobotError` if there is none."""
    if not isinstance(name_or_path, (str, Path)) or not str(name_or_path).strip():
        raise RobotError(f"a robot is a built-in name or a robot YAML path, got {name_or_path!r}")
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or "/" in str(name_or_path) or p.is_file():
        if not p.is_file():
            raise RobotError(f"robot file not found: {p}")
        return p.resolve()
    builtin = MODELS_DIR / str(name_or_path) / "robot.yaml"
    if not builtin.is_file():
        raise RobotError(f"unknown robot {str(name_or_path)!r} (built-in robots: {known_robots()}; or give a YAML path)")
    return builtin


def load_robot(name_or_path: str | Path | Robot) -> Robot:
    """Read and check a robot file (by built-in name or path); a :class:`Robot` is returned as is."""
    if isinstance(name_or_path, Robot):
        return name_or_path
    return _load_cached(robot_file(name_or_path))


@functools.lru_cache(maxsize=32)
def _load_cached(path: Path) -> Robot:
    from besdrake.robot_file import robot_from_dict

    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError) as err:
        raise RobotError(f"{path}: cannot read the robot file: {err}") from err
    except yaml.YAMLError as err:
        raise RobotError(f"{path}: not valid YAML: {err}") from err
    return robot_from_dict(data, path)


def expand_path(value: str, folder: Path) -> Path:
    """A path from a robot file: ``{sys_prefix}`` (the Python environment's prefix) and ``{site_packages}`` (its
    site-packages folder, where pip puts e.g. example-robot-data's ``cmeel.prefix``) expanded, relative paths read
    from ``folder``."""
    import sysconfig

    text = str(value).replace("{sys_prefix}", sys.prefix).replace("{site_packages}", sysconfig.get_paths()["purelib"])
    p = Path(text)
    return p if p.is_absolute() else (folder / p).resolve()
