"""Reading a robot description file: every field checked, the names against the model itself.

Each check raises :class:`~besdrake.robot.RobotError` with one line that names the file and the field,
e.g. ``my_arm.yaml: joints[2].position: lower limit 1.2 above upper limit 0.5``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from besdrake.robot import (
    END_EFFECTOR_TYPES,
    MODELS_DIR,
    PACKAGE_NAME,
    _TOP_KEYS,
    EndEffector,
    Gripper,
    JointLimits,
    Robot,
    RobotError,
    SafetyDefaults,
    expand_path,
)


class _Reader:
    """Field access with errors that name the file and the field."""

    def __init__(self, path: Path | None):
        self.path = path

    def fail(self, where: str, message: str) -> RobotError:
        return RobotError(f"{self.path or '<robot>'}: {where}: {message}")

    def mapping(self, value: Any, where: str) -> dict:
        if not isinstance(value, dict):
            raise self.fail(where, f"must be a mapping, got {type(value).__name__}")
        return value

    def text(self, sec: dict, key: str, where: str, default: str | None = None) -> str:
        if key not in sec or sec[key] is None:
            if default is None:
                raise self.fail(f"{where}{key}", "missing")
            return default
        if not isinstance(sec[key], str) or not sec[key].strip():
            raise self.fail(f"{where}{key}", f"must be a non-empty string, got {sec[key]!r}")
        return sec[key]

    def number(self, value: Any, where: str, low: float | None = None, positive: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
            raise self.fail(where, f"must be a finite number, got {value!r}")
        if positive and value <= 0:
            raise self.fail(where, f"must be > 0, got {value!r}")
        if low is not None and value < low:
            raise self.fail(where, f"must be >= {low}, got {value!r}")
        return float(value)

    def vector(self, value: Any, n: int, where: str, positive: bool = False) -> np.ndarray:
        if not isinstance(value, (list, tuple)) or len(value) != n:
            raise self.fail(where, f"must be a list of {n} numbers, got {value!r}")
        return np.array([self.number(v, f"{where}[{i}]", positive=positive) for i, v in enumerate(value)])


def robot_from_dict(data: Any, path: Path | None = None) -> Robot:
    """Check a parsed robot file and build the :class:`Robot` (the names are checked against the model)."""
    r = _Reader(path)
    data = r.mapping(data, "<top>")
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise r.fail(sorted(unknown)[0], f"unknown field (allowed: {sorted(_TOP_KEYS)})")
    folder = path.parent if path else Path.cwd()
    model, packages = _model(r, data, folder)
    limits, actuators, effort = _joints(r, data)
    n = limits.n_joints
    ctrl = r.mapping(data.get("controller") or {}, "controller")
    robot = Robot(
        name=r.text(data, "name", ""),
        description=str(data.get("description") or "").strip(),
        path=path,
        model=model,
        packages=packages,
        base_link=r.text(data, "base_link", ""),
        limits=limits,
        actuators=actuators,
        effort=effort,
        tool_frame=r.text(data, "tool_frame", ""),
        end_effector=_end_effector(r, data),
        home=r.vector(data.get("home", [0.0] * n), n, "home"),
        kp=r.vector(ctrl.get("kp", [100.0] * n), n, "controller.kp", positive=True),
        kd=r.vector(ctrl.get("kd", [10.0] * n), n, "controller.kd", positive=True),
        safety=_safety(r, data),
        mapping=dict(r.mapping(data.get("mapping") or {}, "mapping")),
        sources={str(k): str(v) for k, v in r.mapping(data.get("sources") or {}, "sources").items()},
    )
    if not limits.within(robot.home).all():
        raise r.fail("home", f"pose {robot.home.tolist()} is outside the joint limits")
    check_against_model(robot, r)
    return robot


def _model(r: _Reader, data: dict, folder: Path) -> tuple[Path, dict[str, Path]]:
    sec = r.mapping(data.get("model"), "model")
    packages = {}
    for name, value in r.mapping(sec.get("packages") or {}, "model.packages").items():
        p = expand_path(value, folder)
        p = p.parent if p.name == "package.xml" else p
        if not p.is_dir():
            raise r.fail(f"model.packages.{name}", f"folder not found: {p}")
        packages[str(name)] = p
    file = r.text(sec, "file", "model.")
    if file.startswith("package://"):
        pkg, _, rest = file[len("package://"):].partition("/")
        root = MODELS_DIR if pkg == PACKAGE_NAME else packages.get(pkg)
        if root is None:
            raise r.fail("model.file", f"unknown package {pkg!r} (declare it under model.packages)")
        model = root / rest
    else:
        model = expand_path(file, folder)
    if not model.is_file():
        raise r.fail("model.file", f"model file not found: {model}")
    return model, packages


def _joints(r: _Reader, data: dict) -> tuple[JointLimits, tuple[str | None, ...], np.ndarray]:
    joints = data.get("joints")
    if not isinstance(joints, list) or not joints:
        raise r.fail("joints", "must be a non-empty list of joints, base to tool")
    names, pos, vel, acc, acts, eff = [], [], [], [], [], []
    for i, j in enumerate(joints):
        where = f"joints[{i}]"
        j = r.mapping(j, where)
        names.append(r.text(j, "name", f"{where}."))
        lim = j.get("position")
        if not isinstance(lim, (list, tuple)) or len(lim) != 2:
            raise r.fail(f"{where}.position", f"must be [lower, upper] in rad, got {lim!r}")
        lo, hi = (r.number(v, f"{where}.position") for v in lim)
        if lo >= hi:
            raise r.fail(f"{where}.position", f"lower limit {lo:g} is not below the upper limit {hi:g}")
        pos.append((lo, hi))
        vel.append(r.number(j.get("velocity"), f"{where}.velocity", positive=True))
        acc.append(r.number(j.get("acceleration"), f"{where}.acceleration", positive=True))
        eff.append(r.number(j.get("effort", float("inf")), f"{where}.effort", positive=True) if "effort" in j else np.inf)
        act = j.get("actuator", f"{names[-1]}_motor")
        if act is not None and not isinstance(act, str):
            raise r.fail(f"{where}.actuator", f"must be an actuator name (null: add one), got {act!r}")
        acts.append(act)
    if len(set(names)) != len(names):
        raise r.fail("joints", f"joint names repeat: {names}")
    return JointLimits(tuple(names), np.array(pos), np.array(vel), np.array(acc)), tuple(acts), np.array(eff)


def _end_effector(r: _Reader, data: dict) -> EndEffector:
    sec = r.mapping(data.get("end_effector"), "end_effector")
    kind = r.text(sec, "type", "end_effector.")
    if kind not in END_EFFECTOR_TYPES:
        raise r.fail("end_effector.type", f"must be one of {list(END_EFFECTOR_TYPES)}, got {kind!r}")
    params = dict(r.mapping(sec.get("params") or {}, "end_effector.params"))
    gripper = _gripper(r, sec) if kind == "gripper" else None
    if kind == "fixed" and "joints" in sec:
        raise r.fail("end_effector.joints", "a fixed end effector has no joints (use type: gripper)")
    return EndEffector(kind, r.text(sec, "body", "end_effector."), gripper, params)


def _gripper(r: _Reader, sec: dict) -> Gripper:
    joints = sec.get("joints")
    if not isinstance(joints, list) or not joints or not all(isinstance(j, str) for j in joints):
        raise r.fail("end_effector.joints", f"a gripper needs a list of joint names, got {joints!r}")
    n = len(joints)
    acts = sec.get("actuators", [f"{j}_motor" for j in joints])
    if not isinstance(acts, list) or len(acts) != n or not all(a is None or isinstance(a, str) for a in acts):
        raise r.fail("end_effector.actuators", f"must list {n} actuator names (null: add one), got {acts!r}")
    coupled = sec.get("coupled_joints", [])
    if not isinstance(coupled, list) or not all(isinstance(j, str) for j in coupled):
        raise r.fail("end_effector.coupled_joints", f"must be a list of joint names, got {coupled!r}")
    return Gripper(
        coupled=tuple(coupled),
        joints=tuple(joints),
        actuators=tuple(acts),
        open=r.vector(sec.get("open"), n, "end_effector.open"),
        closed=r.vector(sec.get("closed"), n, "end_effector.closed"),
        kp=r.vector(sec.get("kp", [100.0] * n), n, "end_effector.kp", positive=True),
        kd=r.vector(sec.get("kd", [10.0] * n), n, "end_effector.kd", positive=True),
        effort=r.vector(sec.get("effort", [100.0] * n), n, "end_effector.effort", positive=True),
    )


def _safety(r: _Reader, data: dict) -> SafetyDefaults:
    sec = r.mapping(data.get("safety") or {}, "safety")
    allowed = set(SafetyDefaults.__dataclass_fields__)
    if set(sec) - allowed:
        raise r.fail(f"safety.{sorted(set(sec) - allowed)[0]}", f"unknown field (allowed: {sorted(allowed)})")
    return SafetyDefaults(**{k: r.number(v, f"safety.{k}", positive=True) for k, v in sec.items()})


def check_against_model(robot: Robot, r: _Reader | None = None) -> None:
    """Parse the model into a scratch plant and check that every named joint, actuator, link and frame
    exists there (:class:`RobotError` naming the field otherwise)."""
    from pydrake.multibody.plant import MultibodyPlant

    r = r or _Reader(robot.path)
    plant = MultibodyPlant(0.0)
    try:
        instance = robot.add_model(plant)
    except RuntimeError as err:
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise r.fail("model.file", f"Drake cannot load {robot.model}: {first}") from err
    except KeyError as err:
        raise r.fail("joints", f"the model has no such joint: {err}") from err
    _check_names(robot, plant, instance, r)


def _check_names(robot: Robot, plant, instance, r: _Reader) -> None:
    joints = {plant.get_joint(i).name() for i in plant.GetJointIndices(instance)}
    for i, name in enumerate(robot.joint_names):
        if name not in joints:
            raise r.fail(f"joints[{i}].name", f"the model has no joint {name!r} (joints: {sorted(joints)})")
    gripper = robot.end_effector.gripper
    for i, name in enumerate(gripper.joints if gripper else ()):
        if name not in joints:
            raise r.fail(f"end_effector.joints[{i}]", f"the model has no joint {name!r} (joints: {sorted(joints)})")
    for i, name in enumerate(gripper.coupled if gripper else ()):
        if name not in joints:
            raise r.fail(f"end_effector.coupled_joints[{i}]", f"the model has no joint {name!r} (joints: {sorted(joints)})")
    for i, act in enumerate(robot.actuators):
        if act is not None and not plant.HasJointActuatorNamed(act, instance):
            raise r.fail(f"joints[{i}].actuator", f"the model has no actuator {act!r} (null adds one)")
    for i, act in enumerate(gripper.actuators if gripper else ()):
        if act is not None and not plant.HasJointActuatorNamed(act, instance):
            raise r.fail(f"end_effector.actuators[{i}]", f"the model has no actuator {act!r} (null adds one)")
    for key, frame in (("base_link", robot.base_link), ("tool_frame", robot.tool_frame)):
        if not plant.HasFrameNamed(frame, instance):
            raise r.fail(key, f"the model has no frame {frame!r}")
    if not plant.HasBodyNamed(robot.end_effector.body, instance):
        raise r.fail("end_effector.body", f"the model has no body {robot.end_effector.body!r}")
