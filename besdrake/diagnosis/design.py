"""Experiment design for a diagnosis: the plans to log so that causes can be told apart.

Two things make a log diagnosable: *diversity* (plans spread out, so that effects with different signatures
predict different outcome patterns) and *repeats* (the same plan run again measures the noise floor directly, the
pure error against which "explained" is tested). Which plans do that is the task's knowledge: its
:meth:`~besdrake.diagnosis.trials.TrialModel.design_experiments` (e.g. diverse plans with repeats and probes that
show what the plain plans hardly do).
"""

from __future__ import annotations

from besdrake.plan import MotionPlan


def diagnosis_plans(n: int = 25, repeats: int = 8, seed: int = 0, limits=None, task: str | None = None, **options) -> list[MotionPlan]:
    """``n`` plans of ``task``'s designed diagnosis experiment (default: the default task's), ``repeats`` of them a
    second run of an earlier plan, seeded with ``seed``, within the robot's joint ``limits``; ``options`` are the
    task's (e.g. how many probes). :class:`ValueError` for a bad request."""
    from besdrake.task import DEFAULT_TASK, TaskError, get_task

    try:
        model = get_task(task or DEFAULT_TASK).diagnosis_model()
    except TaskError as err:
        raise ValueError(str(err)) from None
    return model.design_experiments(n, repeats, seed=seed, limits=limits, **options)


__all__ = ["diagnosis_plans"]
