"""The pick-and-place lab's configuration: a YAML file found by name like the throwing labs
(``diagrams/labs/pick_and_place_lab.yaml``, ``--lab pick_and_place_lab``)::

    name: pick_and_place_lab
    description: public text (written into logs; do not describe the hidden effects here)
    scenario: pick_and_place          # a pick-and-place scenario (name or path relative to this file)
    robot: iiwa14                     # optional: the robot on it (built-in name or robot YAML); default: the scenario's
    seed: 0
    effects:                          # the hidden truth; never written into a log
      box_pose_offset: {x: 0.012, y: -0.008, yaw: 0.05}   # true minus perceived box pose on the shelf (world; m, m, rad)
      box_mass: 0.25                  # kg, the box's true mass
      pad_friction: 0.7               # the finger pads' true friction coefficient
      joint_offset: {joint2: 0.01}    # any further registry effect the pick-and-place task lists (``{param: value}``)
    noise:
      placement_sd: 0.003             # m per axis (x, y): where the box is put on the shelf, trial to trial
      placement_yaw_sd: 0.02          # rad, its yaw, trial to trial
      pose_noise_sd: 0.001            # m per axis: the camera's box position (and lift, slip)
      angle_noise_sd: 0.01            # rad per axis: the camera's box orientation
      encoder_noise_sd: 0.0005        # rad per joint sample
      joint_rate_hz: 100              # Hz, joint log rate (the simulation logs its state at 100 Hz)
    record_joints: true
    home_pose: [...]                  # optional: where the arm stands before its first trial (rad, one per joint)

Every field is checked when the file is read: a mistake is one :class:`~besdrake.transfer.lab_config.LabConfigError`
naming the file and the field.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from besdrake.transfer.lab_config import LabConfigError, _bool, _number, _seed, read_lab_yaml, scenario_path

#: (low, high) of each hidden effect's parameters (SI units); the box pose offset's are those of the registry's
#: ``box_pose_offset`` effect (:mod:`besdrake.tasks.pick_and_place.effects`), which the lab hides them with.
EFFECT_RANGES: dict[str, Any] = {
    "box_pose_offset": {"x": (-0.05, 0.05), "y": (-0.05, 0.05), "yaw": (-0.3, 0.3)},
    "box_mass": (0.05, 1.2),
    "pad_friction": (0.01, 1.0),
}


@dataclass(frozen=True)
class HiddenEffects:
    """What the simulation does not know: the box's true pose offset on the shelf (world x, y in m, yaw in rad: true
    minus perceived), its true mass (kg) and the pads' true friction coefficient (None: as simulated); ``other``:
    further registry effects ``{name: {param: value}}`` the pick-and-place task lists (e.g. ``joint_offset``)."""

    box_pose_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    box_mass: float | None = None
    pad_friction: float | None = None
    other: dict = field(default_factory=dict)

    def registry(self, model_mass: float, model_pad_friction: float) -> dict[str, dict[str, float]]:
        """The hidden truth as the registry's effects (:mod:`besdrake.tasks.pick_and_place.effects`), for a box model
        of ``model_mass`` kg and pads of friction ``model_pad_friction``."""
        out = {k: dict(v) for k, v in self.other.items()}
        if any(self.box_pose_offset):
            out["box_pose_offset"] = dict(zip(("x", "y", "yaw"), (float(v) for v in self.box_pose_offset)))
        if self.box_mass is not None:
            out["box_mass"] = {"delta": float(self.box_mass) - model_mass}
        if self.pad_friction is not None:
            out["pad_friction"] = {"scale": float(self.pad_friction) / model_pad_friction}
        return out


@dataclass(frozen=True)
class PickPlaceNoise:
    """Trial-to-trial placement of the box and the lab's measurement noise (see the module docstring)."""

    placement_sd: float = 0.003
    placement_yaw_sd: float = 0.02
    pose_noise_sd: float = 0.001
    angle_noise_sd: float = 0.01
    encoder_noise_sd: float = 0.0005
    joint_rate_hz: float = 100.0

    RANGES = {
        "placement_sd": (0.0, 0.02),
        "placement_yaw_sd": (0.0, 0.2),
        "pose_noise_sd": (0.0, 0.05),
        "angle_noise_sd": (0.0, 0.2),
        "encoder_noise_sd": (0.0, 0.1),
        "joint_rate_hz": (1.0, 1000.0),
    }

    def sensors(self) -> dict[str, float]:
        """The public sensor facts (written into logs)."""
        return {"box_pose_noise_sd_m": self.pose_noise_sd, "box_angle_noise_sd_rad": self.angle_noise_sd,
                "joint_rate_hz": self.joint_rate_hz, "encoder_noise_sd_rad": self.encoder_noise_sd}


@dataclass
class PickPlaceLabConfig:
    """A validated pick-and-place lab configuration."""

    name: str
    scenario: str = "pick_and_place"
    robot: str | None = None
    effects: HiddenEffects = field(default_factory=HiddenEffects)
    noise: PickPlaceNoise = field(default_factory=PickPlaceNoise)
    seed: int = 0
    record_joints: bool = True
    description: str = ""
    path: Path | None = None
    home_pose: tuple[float, ...] | None = None

    def with_seed(self, seed: int) -> "PickPlaceLabConfig":
        """A copy with another noise seed."""
        new = copy.deepcopy(self)
        new.seed = _seed(seed, "seed")
        return new

    def with_effects(self, effects: HiddenEffects) -> "PickPlaceLabConfig":
        """A copy with other hidden effects (e.g. none: ``HiddenEffects()``)."""
        new = copy.deepcopy(self)
        new.effects = effects
        return new

    def load_scenario(self):
        """The lab's scenario with its robot."""
        from besdrake.sim.scenario import load_scenario

        scenario = load_scenario(self.scenario)
        return scenario if self.robot is None else scenario.with_robot(self.robot)


def _mapping(key: str, value: Any) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise LabConfigError(f"lab config field {key} must be a mapping, got {value!r}")
    return value


def _effects(data: Any) -> HiddenEffects:
    from besdrake.sim.effects import EffectError, normalize_effects
    from besdrake.task import get_task

    d = _mapping("effects", data)
    listed = get_task("pick_and_place").effects
    unknown = sorted(set(d) - set(EFFECT_RANGES) - set(listed))
    if unknown:
        raise LabConfigError(f"lab config effects has unknown effect(s) {unknown}; known: {sorted(set(EFFECT_RANGES) | set(listed))}")
    other = {k: v for k, v in d.items() if k not in EFFECT_RANGES}
    try:
        other = normalize_effects(other)
    except EffectError as err:
        raise LabConfigError(f"lab config effects: {err}") from None
    offset = _mapping("effects.box_pose_offset", d.get("box_pose_offset"))
    ranges = EFFECT_RANGES["box_pose_offset"]
    unknown = sorted(set(offset) - set(ranges))
    if unknown:
        raise LabConfigError(f"lab config effects.box_pose_offset has unknown field(s) {unknown}; known: x, y, yaw")
    pose = tuple(_number(f"effects.box_pose_offset.{k}", offset.get(k, 0.0), *ranges[k]) for k in ("x", "y", "yaw"))
    scalar = {k: None if d.get(k) is None else _number(f"effects.{k}", d[k], *EFFECT_RANGES[k]) for k in ("box_mass", "pad_friction")}
    return HiddenEffects(box_pose_offset=pose, other=other, **scalar)


def _noise(data: Any) -> PickPlaceNoise:
    d = _mapping("noise", data)
    unknown = sorted(set(d) - set(PickPlaceNoise.RANGES))
    if unknown:
        raise LabConfigError(f"lab config noise has unknown field(s) {unknown}; known: {sorted(PickPlaceNoise.RANGES)}")
    return PickPlaceNoise(**{k: _number(f"noise.{k}", v, *PickPlaceNoise.RANGES[k]) for k, v in d.items()})


def _scenario_and_robot(data: dict, base_dir: Path | None) -> tuple[str, str | None, Any]:
    """The scenario (resolved), the robot field (resolved) and the loaded scenario with that robot, checked."""
    from besdrake.robot import RobotError
    from besdrake.sim.scenario import ScenarioError

    scenario = scenario_path(data.get("scenario", "pick_and_place"), base_dir)
    robot = data.get("robot")
    if robot is not None:
        if not isinstance(robot, str) or not robot:
            raise LabConfigError(f"lab config field robot must be a robot name or robot YAML path, got {robot!r}")
        if base_dir is not None and robot.endswith((".yaml", ".yml")) and (base_dir / robot).is_file():
            robot = str(base_dir / robot)
    cfg = PickPlaceLabConfig(name="check", scenario=scenario, robot=robot)
    try:
        loaded = cfg.load_scenario()
    except ScenarioError as err:
        raise LabConfigError(f"lab config scenario: {err}") from err
    except (RobotError, OSError) as err:
        raise LabConfigError(f"lab config field robot: {err}") from err
    if loaded.task != "pick_and_place":
        raise LabConfigError(f"lab config field scenario: {scenario!r} is a {loaded.task!r} scenario, not pick_and_place")
    from besdrake.task import get_task

    try:
        get_task("pick_and_place").check_robot(loaded.robot)
    except RobotError as err:
        raise LabConfigError(f"lab config field robot: {err}") from err
    return scenario, robot, loaded


KNOWN = {"name", "description", "scenario", "robot", "seed", "effects", "noise", "record_joints", "home_pose"}


def parse_pick_place_lab_config(data: Any, base_dir: Path | None = None, name: str = "lab") -> PickPlaceLabConfig:
    """Validate a pick-and-place lab config mapping (as read from YAML); paths resolve against ``base_dir``."""
    if not isinstance(data, dict):
        raise LabConfigError(f"a lab config must be a mapping, got {type(data).__name__}")
    unknown = sorted(set(data) - KNOWN)
    if unknown:
        raise LabConfigError(f"lab config has unknown field(s) {unknown}; known: {sorted(KNOWN)}")
    lab_name = data.get("name", name)
    if not isinstance(lab_name, str) or not lab_name:
        raise LabConfigError(f"lab config field name must be a non-empty string, got {lab_name!r}")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise LabConfigError("lab config field description must be text")
    effects, noise = _effects(data.get("effects")), _noise(data.get("noise"))
    scenario, robot, loaded = _scenario_and_robot(data, base_dir)
    home = data.get("home_pose")
    if home is not None:
        n = loaded.robot.n_joints
        if not isinstance(home, list) or len(home) != n:
            raise LabConfigError(f"lab config field home_pose must be a list of {n} joint positions (rad), got {home!r}")
        lim = loaded.robot.position_limits
        home = tuple(_number(f"home_pose[{i}]", v, lim[i, 0], lim[i, 1]) for i, v in enumerate(home))
    return PickPlaceLabConfig(
        name=lab_name, scenario=scenario, robot=robot, effects=effects, noise=noise,
        seed=_seed(data.get("seed", 0), "seed"), record_joints=_bool("record_joints", data.get("record_joints", True)),
        description=description.strip(), home_pose=home,
    )


def load_pick_place_lab_config(path: str | Path) -> PickPlaceLabConfig:
    """Read and validate a pick-and-place lab YAML file (a path or a built-in lab's name); :class:`LabConfigError`
    naming the file and the field."""
    data, p = read_lab_yaml(path)
    try:
        cfg = parse_pick_place_lab_config(data, base_dir=p.resolve().parent, name=p.stem)
    except ValueError as err:
        raise LabConfigError(f"{p}: {err}") from err
    cfg.path = p
    return cfg


__all__ = ["EFFECT_RANGES", "HiddenEffects", "PickPlaceLabConfig", "PickPlaceNoise", "load_pick_place_lab_config",
           "parse_pick_place_lab_config"]
