"""A lab that replays a measured-data log: :class:`RecordedLab`.

``RecordedLab(logdir).execute(plan)`` returns what the log measured for the same plan (matched by
:func:`~besdrake.transfer.measurement.plan_hash`, i.e. by the trajectory, not the plan's name). A plan
logged several times replays its trials in logged order, then starts over. The replayed measurement gets
the recorded lab's trial number; ``meta["recorded_trial"]`` names the logged trial it came from.
"""

from __future__ import annotations

import copy
from pathlib import Path

from besdrake.plan import MotionPlan
from besdrake.transfer.lab import TrialCounter
from besdrake.transfer.log import LabLog
from besdrake.transfer.measurement import Measurement, plan_hash


class PlanNotRecordedError(KeyError, ValueError):
    """The plan was never executed in the replayed log."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class RecordedLab(TrialCounter):
    """Replays the measured-data log in ``logdir`` (see the module docstring)."""

    def __init__(self, logdir: str | Path) -> None:
        self.log = LabLog.open(logdir)
        self.name = f"recorded:{self.log.lab.get('name', Path(logdir).name)}"
        #: The Measurement class of the replayed log (a task's for a version-2 log).
        self.measurement_type = self.log.measurement_type
        self._trials: dict[str, list[int]] = {}
        for k, h in enumerate(self.log.plan_hashes()):
            self._trials.setdefault(h, []).append(k)
        self._uses: dict[str, int] = {}

    @property
    def robot(self):
        """The logged lab's robot: named in the log's lab description (older logs: their scenario's robot)."""
        from besdrake.robot import load_robot
        from besdrake.sim.scenario import load_scenario

        lab = self.log.lab
        return load_robot(lab["robot"]) if "robot" in lab else load_scenario(lab.get("scenario", "nominal")).robot

    def __len__(self) -> int:
        return len(self.log)

    def description(self) -> dict:
        d = dict(self.log.lab)
        d["name"] = self.name
        d["kind"] = "recorded"
        d["replays"] = str(self.log.root)
        return d

    def has(self, plan: MotionPlan) -> bool:
        """True when ``plan`` was logged."""
        return plan_hash(plan) in self._trials

    def execute(self, plan: MotionPlan, trial: int | None = None) -> Measurement:
        """The logged measurement of ``plan``; :class:`PlanNotRecordedError` if it was never logged."""
        if not isinstance(plan, MotionPlan):
            raise TypeError(f"RecordedLab.execute needs a MotionPlan, got {type(plan).__name__}")
        h = plan_hash(plan)
        trials = self._trials.get(h)
        if not trials:
            raise PlanNotRecordedError(
                f"plan {plan.meta.get('name', '')!r} (hash {h[:12]}...) was never executed in the log {self.log.root} "
                f"({len(self.log)} trials, {len(self._trials)} distinct plans)"
            )
        trial = self.next_trial(trial)
        use = self._uses.get(h, 0)
        self._uses[h] = use + 1
        recorded = self.log.measurement(trials[use % len(trials)])
        m = copy.copy(recorded)
        m.trial = trial
        m.meta = dict(recorded.meta, recorded_trial=recorded.trial, lab=self.name)
        return m


__all__ = ["PlanNotRecordedError", "RecordedLab"]
