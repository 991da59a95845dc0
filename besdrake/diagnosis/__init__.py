"""Diagnosis: what the simulation gets wrong, its cause, the refined model and the gain.

Public API::

    from besdrake.diagnosis import diagnose, Diagnosis, diagnosis_plans, write_report
"""

from besdrake.diagnosis.core import Cause, Diagnosis, DiagnosisError, Gain, diagnose
from besdrake.diagnosis.design import diagnosis_plans

__all__ = ["diagnose", "Diagnosis", "Cause", "Gain", "DiagnosisError", "diagnosis_plans", "write_report"]


def __getattr__(name):  # matplotlib only when a report is written
    if name == "write_report":
        from besdrake.diagnosis.report import write_report

        return write_report
    raise AttributeError(name)
