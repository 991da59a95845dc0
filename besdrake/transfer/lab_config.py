"""Lab configurations as YAML files, for any task: where they are found, how they are read, and which task's lab
they open.

A lab YAML names its ``scenario`` (built-in name or path relative to the file); the scenario names the task
(``task: ...``), and the task builds its lab from the file (:meth:`besdrake.task.Task.make_lab`)::

    lab = open_lab("default_lab")              # diagrams/labs/default_lab.yaml -> its task's virtual lab
    lab = open_lab("pick_and_place_lab", seed=3)

The helpers here check one field each and raise :class:`LabConfigError` naming it; :func:`read_lab_yaml` prefixes
the file, so every mistake is one line naming the file and the field.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml


class LabConfigError(ValueError):
    """A lab configuration (YAML) is missing, unreadable or has an invalid field; the message names it."""


def _number(key: str, value: Any, low: float, high: float) -> float:
    """``value`` as a float in [low, high]; :class:`LabConfigError` naming ``key`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise LabConfigError(f"lab config field {key} must be a number, got {value!r}")
    v = float(value)
    if not np.isfinite(v) or not (low <= v <= high):
        raise LabConfigError(f"lab config field {key}={value!r} is outside [{low:g}, {high:g}]")
    return v


def _seed(value: Any, key: str) -> int:
    """``value`` as a non-negative int; :class:`LabConfigError` naming ``key`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise LabConfigError(f"lab config field {key} must be a non-negative integer, got {value!r}")
    return int(value)


def _bool(key: str, value: Any) -> bool:
    """``value`` if it is a bool; :class:`LabConfigError` naming ``key`` otherwise."""
    if not isinstance(value, bool):
        raise LabConfigError(f"lab config field {key} must be true or false, got {value!r}")
    return value


def resolve_lab_path(path: str | Path) -> Path:
    """``path`` as given where it names a file; else a built-in lab by name (``default_lab`` is
    ``besdrake/diagrams/labs/default_lab.yaml``) or a relative path looked up in the installed package
    (``diagrams/labs/default_lab.yaml`` works from any working folder). Unchanged when none exists."""
    p = Path(path)
    if p.is_file() or p.is_absolute():
        return p
    from besdrake.sim.scenario import DIAGRAMS_DIR

    for q in (DIAGRAMS_DIR / "labs" / f"{p}.yaml", DIAGRAMS_DIR.parent / p):
        if q.is_file():
            return q
    return p


def read_lab_yaml(path: str | Path) -> tuple[Any, Path]:
    """The parsed YAML of a lab file (see :func:`resolve_lab_path`) and its resolved path; :class:`LabConfigError`
    naming the file when it is missing or not YAML."""
    p = resolve_lab_path(path)
    if not p.is_file():
        raise LabConfigError(f"lab config file not found: {p}")
    try:
        return yaml.safe_load(p.read_text(encoding="utf-8")), p
    except (yaml.YAMLError, UnicodeDecodeError) as err:
        raise LabConfigError(f"lab config {p} is not valid YAML: {err}") from err


def scenario_path(scenario: Any, base_dir: Path | None) -> str:
    """A lab's ``scenario`` field checked and resolved: a path relative to the lab file where that file exists,
    else as given (a built-in scenario's name)."""
    if not isinstance(scenario, str) or not scenario:
        raise LabConfigError(f"lab config field scenario must be a scenario name or path, got {scenario!r}")
    if base_dir is not None and (scenario.endswith((".yaml", ".yml")) or "/" in scenario) and not Path(scenario).is_absolute():
        candidate = base_dir / scenario
        if candidate.exists():
            return str(candidate)
    return scenario


def lab_task(data: Any, base_dir: Path | None = None) -> str:
    """The task whose lab a config describes: its scenario's task (scenario default: ``nominal``)."""
    from besdrake.sim.scenario import ScenarioError, load_scenario

    if not isinstance(data, dict):
        raise LabConfigError(f"a lab config must be a mapping, got {type(data).__name__}")
    try:
        return load_scenario(scenario_path(data.get("scenario", "nominal"), base_dir)).task
    except ScenarioError as err:
        raise LabConfigError(f"lab config scenario: {err}") from err


def open_lab(lab: str | Path | dict, seed: int | None = None):
    """The virtual lab a config describes (a lab YAML path, a built-in lab's name, or a mapping), built by its
    scenario's task (:meth:`besdrake.task.Task.make_lab`); ``seed`` replaces the config's noise seed."""
    from besdrake.task import TaskError, get_task

    if isinstance(lab, dict):
        data, where, base = lab, "", None
    else:
        data, path = read_lab_yaml(lab)
        where, base = f"{path}: ", path.resolve().parent
    try:
        task = get_task(lab_task(data, base))
    except (LabConfigError, TaskError) as err:
        raise LabConfigError(f"{where}{err}") from err
    if seed is not None:
        _seed(seed, "seed")
    return task.make_lab(lab if isinstance(lab, dict) else path, seed=seed)


__all__ = ["LabConfigError", "lab_task", "open_lab", "read_lab_yaml", "resolve_lab_path", "scenario_path"]
