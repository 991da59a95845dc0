"""Executors: the same inputs give the same Outcomes on every backend."""

from __future__ import annotations

import builtins

import numpy as np
import pytest

from besdrake.plan import PlanError
from besdrake.sim import make_executor
from besdrake.sim.effects import EffectError
from besdrake.sim.executors import ExecutorError
from besdrake.tasks.throwing.throws import default_throw


def _plans():
    return [default_throw(amplitude=a, yaw=y) for a, y in [(0.3, 0.0), (0.45, 0.2), (0.2, -0.1)]]


EFFECTS = [None, {"base_offset": {"z": 0.05}}, {"air_drag": {"cd": 0.4}}]


def _same(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert x.flags == y.flags
        assert np.array_equal(x.touchdown, y.touchdown)
        assert np.array_equal(x.ball_path, y.ball_path)


@pytest.fixture(scope="module")
def serial_out():
    with make_executor("serial") as ex:
        return ex.evaluate(_plans(), effects=EFFECTS)


def test_serial_keeps_order_and_applies_per_plan_effects(serial_out):
    assert all(o.ok for o in serial_out)
    assert serial_out[1].effects["base_offset"]["z"] == 0.05
    assert serial_out[0].effects == {}
    assert serial_out[1].touchdown[1] > 0.1 and serial_out[2].touchdown[1] < 0


def test_process_pool_matches_serial(serial_out):
    with make_executor("process", workers=2) as ex:
        out = ex.evaluate(_plans(), effects=EFFECTS)
        again = ex.evaluate(list(reversed(_plans())), effects=list(reversed(EFFECTS)))
    _same(out, serial_out)
    _same(list(reversed(again)), serial_out)


def test_one_effect_dict_for_all_plans():
    with make_executor("serial") as ex:
        out = ex.evaluate(_plans()[:2], effects={"base_offset": {"z": 0.05}})
    assert all(o.effects["base_offset"]["z"] == 0.05 for o in out)


def test_bad_inputs_fail_in_the_caller():
    ex = make_executor("serial")
    bad = default_throw()
    bad.q[3, 1] = np.nan
    with pytest.raises(PlanError, match="plan 1: .*NaN"):
        ex.evaluate([default_throw(), bad])
    with pytest.raises(EffectError, match="unknown effect"):
        ex.evaluate([default_throw()], effects={"teleport": {}})
    with pytest.raises(ValueError, match="2 plans"):
        ex.evaluate(_plans()[:2], effects=[None])
    assert ex.evaluate([]) == []
    ex.close()
    with pytest.raises(ExecutorError, match="closed"):
        ex.evaluate([default_throw()])
    with pytest.raises(ExecutorError, match="unknown executor backend"):
        make_executor("gpu")
    strict = make_executor("serial", limits="raise")
    with pytest.raises(PlanError, match="position limits"):
        strict.evaluate([default_throw(amplitude=4.0)])
    flagged = make_executor("serial").evaluate([default_throw(amplitude=4.0)])
    assert flagged[0].flags["joint_limit_exceeded"]


def test_ray_missing_gives_install_hint(monkeypatch):
    real_import = builtins.__import__

    def no_ray(name, *args, **kwargs):
        if name == "ray" or name.startswith("ray."):
            raise ImportError("No module named 'ray'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    with pytest.raises(ExecutorError, match=r"besdrake\[cluster\]"):
        make_executor("ray", workers=1)


def test_ray_backend_matches_serial(serial_out):
    ray = pytest.importorskip("ray")
    with make_executor("ray", workers=2, num_cpus=2, include_dashboard=False) as ex:
        out = ex.evaluate(_plans(), effects=EFFECTS)
    _same(out, serial_out)
    ray.shutdown()


def test_worker_build_failure_is_reported(monkeypatch):
    from besdrake.sim import load_scenario

    scen = load_scenario("nominal")
    broken = scen.with_overrides(models={**scen.models, "ball": "/nonexistent/ball.sdf"})
    with pytest.raises(ExecutorError, match="could not build the simulation.*not found"):
        make_executor("process", workers=1, scenario=broken)


def test_a_worker_that_dies_fails_its_batch_and_the_pool_recovers():
    import os

    from besdrake.sim.effects import Effect, register_effect, unregister_effect

    class Crash(Effect):
        """Test-only: kills the worker process that simulates it (a crash inside the simulator)."""

        name = "test_crash"
        params = {}

        def apply(self, setup, values):
            os._exit(3)

    register_effect(Crash)  # before the pool forks, so the workers know it
    try:
        with make_executor("process", workers=2) as ex:
            plans = [default_throw(amplitude=a) for a in (0.4, 0.45, 0.5)]
            crashed = ex.evaluate(plans, effects=[None, {"test_crash": {}}, None])
            assert crashed[1].flags["sim_failed"] and "worker died" in crashed[1].message
            after = ex.evaluate(plans)  # the pool was rebuilt
            assert all(o.ok for o in after)
    finally:
        unregister_effect("test_crash")


def test_spawned_workers_load_the_callers_effect_plugins(drag_plugin):
    """An effect registered by a --plugin file simulates in a process pool too (spawned workers do not
    inherit the registry: the executor hands them the plugin files)."""
    from besdrake.plugins import load_plugin

    path, name = drag_plugin
    load_plugin(path)
    plans = [default_throw(0.35)]
    effects = {name: {"cd": 0.9}}
    with make_executor("serial") as ex:
        serial = ex.evaluate(plans, effects)[0]
        plain = ex.evaluate(plans)[0]
    with make_executor("process", workers=1, start_method="spawn") as ex:
        pooled = ex.evaluate(plans, effects)[0]
    assert not pooled.flags["sim_failed"], pooled.message
    assert serial.touchdown[0] < plain.touchdown[0] - 0.02  # the plugin's drag acts
    np.testing.assert_allclose(pooled.touchdown, serial.touchdown, atol=1e-9)
