"""Configuration of ``besdrake learn``: the packaged defaults, a user's YAML, profiles and overrides.

Precedence, lowest first: the task's learn configuration (:attr:`besdrake.task.Task.learn_config`, e.g.
``besdrake/tasks/<name>/learn.yaml``; the default task's where the configuration names none), the ``--quick`` profile
(its ``quick:`` section), the user's ``--config`` file, then ``--set section.key=value`` flags.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import yaml

class ConfigError(ValueError):
    """A configuration file or override that cannot be used (unknown key, bad YAML, wrong type)."""


def deep_merge(base: dict[str, Any], extra: dict[str, Any], where: str = "") -> dict[str, Any]:
    """``base`` updated by ``extra``; unknown keys are errors (a typo must not pass silently)."""
    out = copy.deepcopy(base)
    for key, value in extra.items():
        path = f"{where}{key}"
        if key not in out:
            raise ConfigError(f"unknown configuration key {path!r}; known: {sorted(out)}")
        if isinstance(out[key], dict) and isinstance(value, dict):
            out[key] = deep_merge(out[key], value, f"{path}.")
        elif isinstance(out[key], dict):
            raise ConfigError(f"configuration key {path!r} must be a mapping, got {value!r}")
        else:
            out[key] = value
    return out


def parse_override(text: str) -> dict[str, Any]:
    """``"refinement.evaluations=200"`` -> ``{"refinement": {"evaluations": 200}}`` (value parsed as YAML)."""
    if "=" not in text:
        raise ConfigError(f"override {text!r} must look like section.key=value")
    key, raw = text.split("=", 1)
    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError as err:
        raise ConfigError(f"override {text!r}: {err}") from None
    out: dict[str, Any] = {}
    node = out
    parts = key.strip().split(".")
    for part in parts[:-1]:
        node = node.setdefault(part, {})
    node[parts[-1]] = value
    return out


def _user_config(path: str | Path | None) -> dict[str, Any]:
    if path is None:
        return {}
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"configuration file {path} not found")
    try:
        user = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        raise ConfigError(f"{path}: not valid YAML: {err}") from None
    if not isinstance(user, dict):
        raise ConfigError(f"{path}: the configuration must be a mapping")
    return user


def _defaults(task: Any) -> tuple[dict[str, Any], dict[str, Any]]:
    """The packaged defaults and the ``--quick`` profile of ``task`` (the default task's where ``task`` is None or
    unknown: an unknown task is refused later, with the list of known ones)."""
    from besdrake.task import DEFAULT_TASK, TaskError, get_task

    try:
        own = get_task(str(task)).learn_config if task else None
    except TaskError:
        own = None
    if own is None:
        own = get_task(DEFAULT_TASK).learn_config
    config = yaml.safe_load(Path(own).read_text())
    return config, config.pop("quick", {}) or {}


def load_config(path: str | Path | None = None, quick: bool = False, overrides: list[str] = ()) -> dict[str, Any]:
    """The effective configuration (see the module docstring)."""
    user = _user_config(path)
    parsed = [parse_override(text) for text in overrides]
    task = next((o["task"] for o in reversed(parsed) if "task" in o), user.get("task"))
    config, quick_profile = _defaults(task)
    if quick:
        config = deep_merge(config, quick_profile)
    config = deep_merge(config, user)
    for extra in parsed:
        config = deep_merge(config, extra)
    return config
