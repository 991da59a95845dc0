"""The diagnosis reaches a task's trials only through ``Task.diagnosis_model()`` (issue 23)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from besdrake.diagnosis.trials import TrialModel, model_for
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
