"""Shared pytest configuration: slow tests run only with ``--runslow``."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--runslow", action="store_true", default=False, help="also run tests marked slow")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if config.getoption("--runslow"):
        return
    skip_slow = pytest.mark.skip(reason="slow: run with --runslow")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip_slow)


@pytest.fixture(scope="session")
def script():
    """Load a benchmark or tool from ``scripts/`` as a module: ``script("bench_diagnosis")``."""
    import importlib.util

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, REPO / "scripts" / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    return load


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real recordings in ``../shared/data`` (read-only)."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA}")
    return SHARED_DATA


_DRAG_PLUGIN = '''
from besdrake.sim.effects import Effect, Param, register_effect

@register_effect
class PluginDrag(Effect):
    """Test plugin: air drag on the ball in flight."""
    name = "{name}"
    applied_via = "flight"
    params = {{"cd": Param(0.0, 0.0, 1.0, "1", "drag coefficient")}}
    def apply(self, setup, values):
        setup.drag_coefficient = values["cd"]
'''


@pytest.fixture
def drag_plugin(tmp_path: Path):
    """A user's plugin file (``tmp_path/drag_plugin.py``) registering a drag effect under a unique name:
    yields ``(path, name)``; the effect is unregistered afterwards if the test loaded it."""
    import uuid

    from besdrake.sim.effects import unregister_effect

    name = f"plugin_drag_{uuid.uuid4().hex[:8]}"
    path = tmp_path / "drag_plugin.py"
    path.write_text(_DRAG_PLUGIN.format(name=name))
    yield path, name
    try:
        unregister_effect(name)
    except Exception:  # noqa: BLE001 - the test never loaded it
        pass
