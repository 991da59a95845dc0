"""Sim-to-real: the lab interface, measured-data logs, the Transferability Approach.

* :class:`~besdrake.transfer.lab.Lab` -- ``execute(plan) -> Measurement``: where a real robot plugs in;
  :class:`~besdrake.transfer.lab.SafetyGate` refuses plans beyond the joint limits before any lab runs them;
* :class:`~besdrake.transfer.recorded_lab.RecordedLab` replays a log; :func:`~besdrake.transfer.lab_config.open_lab`
  opens any task's virtual lab (the simulation plus hidden effects and noise) from its YAML (the scenario's task
  builds it: ``Task.make_lab``; e.g. ``besdrake/tasks/<name>/lab.py``);
* :class:`~besdrake.transfer.log.LabLog` -- the measured-data log (format: ``LOG_FORMAT.md``);
* :class:`~besdrake.transfer.transferability.TransferabilityApproach` -- multi-objective search with
  transfers to a lab.
"""

from besdrake.transfer.lab import Lab, SafetyGate
from besdrake.transfer.lab_config import LabConfigError, open_lab
from besdrake.transfer.log import LabLog, read_log
from besdrake.transfer.measurement import Measurement, plan_hash
from besdrake.transfer.recorded_lab import RecordedLab

__all__ = [
    "Lab",
    "LabConfigError",
    "LabLog",
    "Measurement",
    "RecordedLab",
    "SafetyGate",
    "open_lab",
    "plan_hash",
    "read_log",
]
