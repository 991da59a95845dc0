"""Load a user's Python file that registers further physical effects or tasks (``--plugin FILE.py``).

A plugin is an ordinary module; importing it runs its ``@register_effect`` decorators
(see :mod:`besdrake.sim.effects`) and ``@register_task`` decorators (see :mod:`besdrake.task`). Each file is loaded once per process, so a lab config and the
command line may both name it. The process and Ray executors load the plugins of the process that
creates them in each worker, so plugin effects simulate in parallel too.
"""

from __future__ import annotations

import hashlib
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

_LOADED: dict[Path, ModuleType] = {}


class PluginError(ValueError):
    """A plugin file is missing, not Python, or failed while being imported."""


def load_plugin(path: str | Path) -> ModuleType:
    """Import the plugin at ``path`` (once per process) and return its module.

    Raises :class:`PluginError` naming the file for a missing file, a syntax error or an exception raised
    while importing it (e.g. an effect registered under a name that is taken)."""
    p = Path(path).expanduser()
    key = p.resolve()
    if key in _LOADED:  # loaded already (a forked worker has its parent's plugins, even of a file deleted since)
        return _LOADED[key]
    if not p.is_file():
        raise PluginError(f"plugin file not found: {p}")
    if p.suffix != ".py":
        raise PluginError(f"plugin must be a Python file (.py): {p}")
    name = "besdrake_plugin_" + p.stem + "_" + hashlib.sha1(str(key).encode()).hexdigest()[:8]
    spec = importlib.util.spec_from_file_location(name, key)
    if spec is None or spec.loader is None:  # pragma: no cover - only for odd file systems
        raise PluginError(f"cannot load plugin {p}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except (Exception, SystemExit) as err:  # a user's file: report any failure (even sys.exit) by name
        sys.modules.pop(name, None)
        raise PluginError(f"plugin {p} failed to load: {type(err).__name__}: {err}") from err
    _LOADED[key] = module
    return module


def loaded_plugin_paths() -> list[Path]:
    """Absolute paths of the plugins loaded in this process, in load order (executors hand them to their workers)."""
    return list(_LOADED)


def load_plugins(paths: list[str | Path]) -> list[ModuleType]:
    """:func:`load_plugin` for each path, in order."""
    return [load_plugin(p) for p in paths]


__all__ = ["PluginError", "load_plugin", "load_plugins", "loaded_plugin_paths"]
