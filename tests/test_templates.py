"""Behaviour templates: meta-parameters, pool save/load, instantiate, BO-CPS direction, failures, resume, CLI."""

from __future__ import annotations

import json
from types import SimpleNamespace
import logging

import numpy as np
import pytest

from besdrake.plan import MotionPlan
from besdrake.search.templates import (
    CONTEXT_BOUNDS,
    TEST_CONTEXTS,
    BehaviorTemplate,
    MetaDMP,
    TemplateError,
    TemplatePool,
    default_meta_bounds,
    evaluate_template,
    touchdowns,
    train_template,
)
from besdrake.tasks.throwing.outcome import FLAG_NAMES, Outcome
from besdrake.tasks.throwing.template_base import default_template_base, fitted_default_throw

logging.getLogger("drake").setLevel(logging.ERROR)


from besdrake.robot import load_robot

COMPI = load_robot("compi")


@pytest.fixture(scope="module")
def base():
    return fitted_default_throw()


class PolarStandIn:
    """Cheap stand-in for the simulation: range 3.3 m - execution time, direction = final joint-1 angle."""

    scenario = SimpleNamespace(name="polar-stand-in", robot=COMPI, effects={})

    def __init__(self, fail_every: int = 0) -> None:
        self.calls = 0
        self.fail_every = fail_every

    def evaluate(self, plans):
        out = []
        for p in plans:
            self.calls += 1
            flags = {k: False for k in FLAG_NAMES}
            if self.fail_every and self.calls % self.fail_every == 0:
                flags["never_released"] = True
                out.append(Outcome(flags=flags))
                continue
            r, yaw = 3.3 - p.duration, p.q[-1, 0]
            out.append(Outcome(flags=flags, touchdown=np.array([r * np.cos(yaw), r * np.sin(yaw)])))
        return out


def test_test_contexts_are_x_forward_y_lateral():
    assert TEST_CONTEXTS.shape == (16, 2)
    assert sorted(set(TEST_CONTEXTS[:, 0])) == [1.3, 1.6, 1.9, 2.2]  # forward
    assert sorted(set(TEST_CONTEXTS[:, 1])) == [-0.7, -0.2, 0.2, 0.7]  # lateral
    assert np.all((TEST_CONTEXTS >= CONTEXT_BOUNDS[:, 0]) & (TEST_CONTEXTS <= CONTEXT_BOUNDS[:, 1]))


def test_meta_dmp_rotate_shifts_joint1_and_goal_mode_keeps_start(base):
    m = MetaDMP(base, COMPI, "rotate")
    tau = base.execution_time
    p0, p1 = m.plan([tau, base.goal[0]]), m.plan([tau, base.goal[0] + 0.4])
    assert np.allclose(p1.q[:, 0], p0.q[:, 0] + 0.4, atol=1e-9)
    assert np.allclose(p1.q[:, 1:], p0.q[:, 1:])
    g = MetaDMP(base, COMPI, "goal").plan([tau, base.goal[0] + 0.4])
    assert g.q[0, 0] == pytest.approx(base.start[0]) and g.q[-1, 0] == pytest.approx(base.goal[0] + 0.4, abs=0.05)
    slow = m.plan([1.5 * tau, base.goal[0]])
    assert slow.duration == pytest.approx(1.5 * tau)
    with pytest.raises(TemplateError):
        m.plan([np.nan, 0.0])
    with pytest.raises(TemplateError):
        m.plan([-1.0, 0.0])
    with pytest.raises(TemplateError):
        MetaDMP(base, COMPI, "sideways")


def test_meta_bounds_respect_minimum_execution_time(base):
    b = default_meta_bounds(base, COMPI)
    assert b[0, 0] >= 0.95 and b[0, 0] < base.execution_time < b[0, 1]
    assert b[1, 0] < base.goal[0] < b[1, 1]


def test_meta_bounds_keep_every_plan_within_the_joint_limits(base):
    free = default_meta_bounds(base, COMPI, respect_limits=False)
    safe = default_meta_bounds(base, COMPI)
    m = MetaDMP(base, COMPI)
    assert not m.plan([free[0, 0], base.goal[0]]).check_limits(COMPI.limits).ok  # the free box allows too fast throws
    assert free[0, 0] < safe[0, 0] < base.execution_time * 1.05
    assert not m.plan([safe[0, 0] - 0.02, base.goal[0]]).check_limits(COMPI.limits).ok  # the bound is tight
    for tau in safe[0]:
        for goal in safe[1]:
            assert m.plan([tau, goal]).check_limits(COMPI.limits).ok

    class Fastest:
        def policy(self, s):
            return np.array([0.0, base.goal[0]])  # asks for an impossibly fast throw

    plan = BehaviorTemplate("fast", m, safe, Fastest()).instantiate([2.4, 0.0])
    assert plan.meta["within_limits"] and plan.duration == pytest.approx(safe[0, 0])
    flagged = BehaviorTemplate("fast", m, free, Fastest()).instantiate([2.4, 0.0])
    assert flagged.meta["within_limits"] is False


@pytest.fixture(scope="module")
def trained(base):
    return train_template(base, PolarStandIn(), method="ucb", n_episodes=25, seed=0, name="polar",
                          checkpoints=(25,), provenance={"base_dmp": "fitted_default_throw"})


def test_template_learns_on_stand_in_and_aims_left_for_left_targets(trained):
    t = trained.template
    left, right = t.meta_parameters([1.8, 0.7]), t.meta_parameters([1.8, -0.7])
    assert left[1] > 0.15 > -0.15 > right[1]  # joint 1 turns towards +y (left) for a target on the left
    near, far = t.meta_parameters([1.2, 0.0]), t.meta_parameters([2.3, 0.0])
    assert near[0] > far[0]  # a farther target gets a faster (shorter) throw
    ev = evaluate_template(t, PolarStandIn())
    assert ev.mean_distance < 0.25
    assert trained.curve[25] == pytest.approx(ev.mean_distance)


def test_pool_round_trip_and_instantiate(trained, tmp_path):
    pool = TemplatePool(tmp_path)
    pool.add(trained.template)
    with pytest.raises(TemplateError, match="already holds"):
        pool.add(trained.template)
    again = TemplatePool(tmp_path)
    assert again.names() == ["polar"]
    assert again.provenance("polar")["method"] == "ucb" and again.provenance("polar")["base_dmp"] == "fitted_default_throw"
    loaded = again.get("polar")
    for s in ([1.4, -0.5], [2.2, 0.7]):
        a, b = trained.template.instantiate(s), loaded.instantiate(s)
        assert isinstance(b, MotionPlan)
        assert np.array_equal(a.q, b.q) and np.array_equal(a.t, b.t)
        assert b.meta["template"] == "polar" and b.meta["context_m"] == s
    assert (tmp_path / "polar.template.json").is_file() and (tmp_path / "polar-policy.npz").is_file()


def test_bad_contexts_and_corrupt_files_are_reported(trained, tmp_path):
    t = trained.template
    with pytest.raises(TemplateError, match="finite"):
        t.instantiate([np.nan, 0.0])
    with pytest.raises(TemplateError, match="two numbers"):
        t.instantiate([1.0, 0.0, 0.0])
    path = t.save(tmp_path)
    (tmp_path / "polar-policy.npz").unlink()
    with pytest.raises(TemplateError, match="missing"):
        BehaviorTemplate.load(path)
    path.write_text("{not json")
    with pytest.raises(TemplateError, match="corrupt"):
        BehaviorTemplate.load(path)
    (tmp_path / "pool.json").write_text("[]")
    with pytest.raises(TemplateError, match="corrupt pool"):
        TemplatePool(tmp_path)
    with pytest.raises(TemplateError, match="no template"):
        TemplatePool(tmp_path / "empty").get("nothing")


def test_failed_episodes_are_kept_and_training_resumes(base, tmp_path):
    ex = PolarStandIn(fail_every=4)
    first = train_template(base, ex, "ucb", 10, seed=1, out_dir=tmp_path)
    assert first.loop.n_evaluations == 10 and first.loop.n_failed == 2
    ex2 = PolarStandIn()
    again = train_template(base, ex2, "ucb", 14, seed=1, out_dir=tmp_path)
    assert again.loop.resumed and again.loop.n_evaluations == 14 and ex2.calls == 4
    assert again.loop.n_failed == 2


def test_es_template_on_the_real_simulation_aims_in_the_right_direction(base):
    from besdrake.sim import make_executor

    with make_executor("serial") as ex:
        tr = train_template(base, ex, "es", 16, seed=0)
        t = tr.template
        left, right = t.meta_parameters([1.7, 0.8]), t.meta_parameters([1.7, -0.8])
        assert left[1] > right[1]
        ev = evaluate_template(t, ex, np.array([[1.7, 0.8], [1.7, -0.8]]))
    assert ev.touchdowns[0, 1] > 0 > ev.touchdowns[1, 1]


def test_default_template_base_reaches_every_test_context_within_the_limits():
    """The template base's fastest and slowest plans within the joint limits bracket every test context's
    distance (the 6-weight fit of the same throw fell 0.19 m short of the farthest ones)."""
    from besdrake.sim import make_executor

    base = default_template_base()
    bounds = default_meta_bounds(base, COMPI)
    meta = MetaDMP(base, COMPI, "rotate")
    plans = [meta.plan(np.array([tau, base.goal[0]])) for tau in bounds[0]]
    assert all(p.check_limits(COMPI.limits).ok for p in plans)
    with make_executor("serial") as ex:
        fastest, slowest = (float(np.linalg.norm(d)) for d in touchdowns(plans, ex))
    distances = np.linalg.norm(TEST_CONTEXTS, axis=1)
    assert fastest > distances.max() + 0.1 and slowest < distances.min()


def test_template_cli_train_list_instantiate(tmp_path):
    from besdrake.cli import main

    pool = tmp_path / "pool"
    common = ["--pool", str(pool), "--backend", "serial", "--quiet"]
    assert main(["template", "train", "default", "--name", "t1", "--method", "ucb", "--episodes", "6", "--no-figures", *common]) == 0
    assert "t1" in TemplatePool(pool)
    plan_file = tmp_path / "plan.json"
    assert main(["template", "instantiate", "t1", "--target", "1.8", "0.3", "--plan-out", str(plan_file), *common]) == 0
    plan = MotionPlan.load(plan_file)
    assert plan.meta["template"] == "t1"
    assert main(["template", "instantiate", "--name", "t1", "--context", "1.8", "0.3", *common]) == 0  # alias form
    assert main(["template", "list", *common]) == 0
    assert main(["template", "instantiate", "t1", *common]) == 2  # no --target
    assert main(["template", "eval", "missing", *common]) == 2
    assert json.loads((pool / "pool.json").read_text())["templates"]["t1"]["provenance"]["method"] == "ucb"


def test_creps_baseline_trains_saves_and_loads(base, tmp_path):
    tr = train_template(base, PolarStandIn(), "creps", 40, seed=0, name="creps")
    assert tr.loop.n_evaluations == 40 and tr.loop.optimizer.n_updates == 2
    pool = TemplatePool(tmp_path)
    pool.add(tr.template)
    s = [1.9, 0.4]
    assert np.array_equal(pool.instantiate("creps", s).q, tr.template.instantiate(s).q)
