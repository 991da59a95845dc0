"""The diagnosis reaches a task's trials only through ``Task.diagnosis_model()`` (issue 23)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from besdrake.diagnosis.trials import Observable, TrialModel, model_for
from besdrake.task import Task, TaskError, get_task, register_task
from besdrake.tasks.throwing.diagnosis import observables as obs
from besdrake.tasks.throwing.diagnosis.model import MODEL


def test_the_throwing_model_matches_its_observables():
    m = get_task("throwing").diagnosis_model()
    assert isinstance(m, TrialModel) and m is MODEL
    assert m.slices() == obs.group_slices() and m.n_features == obs.N_FEATURES and m.units() == obs.GROUP_UNITS
    assert m.outcome in m.names() and m.scatter is not None and m.scatter.effect == "ball_placement"
    pts = m.scatter.points(0.002)
    assert pts.shape == (4, 2) and np.allclose(pts.mean(axis=0), 0.0) and np.allclose(np.abs(pts), 0.002 * np.sqrt(2 / np.pi))


def test_diagnosis_plans_are_the_tasks_design():
    from besdrake.diagnosis import diagnosis_plans
    from besdrake.tasks.throwing.diagnosis.design import diagnosis_plans as throw_plans
    from besdrake.transfer.measurement import plan_hash

    a = diagnosis_plans(12, 3, seed=5, probes=1)
    b = throw_plans(12, 3, seed=5, probes=1)
    assert [plan_hash(p) for p in a] == [plan_hash(p) for p in b]
    with pytest.raises(ValueError, match="unknown task"):
        diagnosis_plans(12, 3, task="no_such_task")


def test_a_task_without_a_diagnosis_model_is_refused():
    @register_task
    class _Mute(Task):
        name = "_mute_for_diagnosis_test"

        def make_rollout(self, scenario, meshcat=None):
            raise NotImplementedError

        def failed_outcome(self, message):
            raise NotImplementedError

    with pytest.raises(TaskError, match="diagnosis_model"):
        model_for(SimpleNamespace(task=_Mute.name))


class _SlideModel(TrialModel):
    """A toy task's trials: where a pushed puck comes to rest (x, y), read straight from the outcome dict."""

    noun = "push"
    observables = (Observable("rest", 2, "m", 0.001, 0.01, "measure where the puck rests", ((0, 1),)),)
    outcome = "rest"
    prior_outcome_sd = 0.01
    prior_outcome_source = "assumed"
    prior_outcome_note = "no repeats"

    def usable(self, m):
        return True, ""

    def make_layout(self, m, nominal):
        return None

    def nominal_layout(self, nominal):
        return None

    def full_layout(self, layout):
        return layout

    def measured_features(self, m, layout):
        return np.asarray(m.rest, float), None

    def simulated_features(self, outcome, layout):
        return np.asarray(outcome["rest"], float)


def _slide(plan, effects: dict) -> dict:
    """The toy physics: the rest point follows the plan's end pose; a base offset shifts it, a lag shortens the push."""
    a, b = float(plan.q[-1, 0]), float(plan.q[-1, 1])
    base = effects.get("base_offset", {})
    tau = effects.get("actuator_lag", {}).get("tau", 0.0)
    return {"rest": [a + base.get("x", 0.0) - 3.0 * tau * a, b + base.get("y", 0.0) + 2.0 * tau * b * b]}


class _SlideExecutor:
    def evaluate(self, plans, effects):
        return [_slide(p, e) for p, e in zip(plans, effects)]


def test_the_engine_diagnoses_another_task_through_its_model():
    """No throwing code on the path: a toy task's log with a hidden base offset is named, fitted and gains held out."""
    import yaml

    from besdrake.diagnosis import diagnose
    from besdrake.plan import MotionPlan
    from besdrake.sim.scenario import DIAGRAMS_DIR, scenario_from_dict

    @register_task
    class _Slide(Task):
        name = "_slide_for_diagnosis_test"

        def make_rollout(self, scenario, meshcat=None):
            raise NotImplementedError

        def failed_outcome(self, message):
            raise NotImplementedError

        def diagnosis_model(self):
            return _SlideModel()

    scen = scenario_from_dict(yaml.safe_load((DIAGRAMS_DIR / "nominal.yaml").read_text()) | {"task": _Slide.name})
    rng = np.random.default_rng(0)
    plans = []
    for i in range(10):
        q = np.zeros((3, 6))
        q[-1, :2] = [0.5 + 0.1 * i, rng.uniform(-0.4, 0.4)]
        plans.append(MotionPlan(t=np.array([0.0, 0.5, 1.0]), q=q, meta={"name": f"push_{i}"}))
    plans += plans[:4]  # repeats measure the noise
    hidden = {"base_offset": {"x": 0.03}}
    log = [SimpleNamespace(trial=i, plan=p, flags={}, rest=np.array(_slide(p, hidden)["rest"]) + rng.normal(0, 0.003, 2))
           for i, p in enumerate(plans)]
    d = diagnose(log, scenario=scen, candidates=["base_offset", "actuator_lag"], executor=_SlideExecutor(), structural=False, folds=3)
    assert d.best.effects == ("base_offset",), d.verdict
    got = {p["parameter"]: p["value"] for p in d.best.parameters}
    assert abs(got["x"] - 0.03) < 0.005, got
    assert d.explained and d.gain.median_disparity_after_m < d.gain.median_disparity_before_m
    # Outcomes alone never vouch for a cause: the toy's own words say so.
    assert d.groups_measured == ["rest"] and d.confidence == "low" and "records only the rest" in d.verdict, d.verdict
