"""What a lab measured for one executed (or refused) motion plan: :class:`Measurement`.

A Measurement is the same whether it comes from the real robot, the virtual lab or a replayed log. It
holds only what a real lab can observe (motion capture, encoders, flags); a virtual lab's hidden effects
never enter it. Units are SI: m, s, rad; positions in the world frame (floor z = 0). A task's lab returns a
subclass with what it observes besides (e.g. a tracked object's marker path), and its own flags.

Flags every lab may raise (all optional; absent means not raised):

* ``refused_by_safety_gate``: the plan exceeded a joint limit and was not run (``message`` lists why);
* ``joint_limit_exceeded``: a measured joint angle went beyond a position limit;
* ``aborted``: the run was stopped (robot switched itself off, controller fault, ...).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from besdrake.plan import MotionPlan

#: Flags any lab may raise (a task's lab adds its own; readers must accept unknown ones).
FLAG_NAMES: tuple[str, ...] = (
    "refused_by_safety_gate",
    "joint_limit_exceeded",
    "aborted",
)


class MeasurementError(ValueError):
    """A measurement (or its serialised form) has missing fields, wrong shapes or non-finite values."""


def plan_hash(plan: MotionPlan) -> str:
    """Content hash of a plan (hex SHA-256 of its float64 ``t``, ``q`` and ``qd``; ``meta`` is ignored but for a
    gripper command).

    Two plans hash equal when they command the same trajectory, whatever their names; JSON round trips
    keep the hash (Python writes floats exactly). A gripper command in ``meta["gripper"]`` (``{"t": [...],
    "width": [...]}``) is commanded too: when present, its ``t`` and ``width`` are hashed after ``qd`` the same way
    (plans without one hash as before).
    """
    h = hashlib.sha256()
    arrays = [("t", plan.t), ("q", plan.q), ("qd", plan.qd)]
    grip = plan.meta.get("gripper") if isinstance(plan.meta, dict) else None
    if isinstance(grip, dict):
        arrays += [("gripper_t", grip.get("t")), ("gripper_width", grip.get("width"))]
    for name, arr in arrays:
        h.update(name.encode())
        if arr is None:
            h.update(b"none")
        else:
            try:
                a = np.ascontiguousarray(np.asarray(arr, dtype="<f8"))
            except (TypeError, ValueError):
                if not name.startswith("gripper"):
                    raise
                h.update(repr(arr).encode())  # a malformed gripper command (the lab refuses it): its text
                continue
            h.update(str(a.shape).encode())
            h.update(a.tobytes())
    return h.hexdigest()


def _arr(x: Any, name: str, cols: int | None) -> np.ndarray | None:
    if x is None:
        return None
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as err:
        raise MeasurementError(f"measurement field {name!r} is not numeric: {err}") from err
    if cols is None:
        if a.ndim != 1:
            raise MeasurementError(f"measurement field {name!r} must be 1-D, got shape {a.shape}")
    else:
        if a.size == 0:
            a = a.reshape(0, cols)
        if a.ndim != 2 or a.shape[1] != cols:
            raise MeasurementError(f"measurement field {name!r} must have shape (n, {cols}), got {a.shape}")
    return a


@dataclass
class Measurement:
    """One trial as a lab measured it (see the module docstring for the flags).

    * ``trial``: 0, 1, 2, ... in the order executed; ``plan``: the :class:`MotionPlan` executed or refused;
    * ``touchdown`` (2,): measured (x, y) on the floor in m where the task's object came down, or None when not seen;
    * ``joint_t`` (K,) s, ``q_commanded``/``q_measured`` (K, n) rad (n: the plan's joints): what the controller was sent and the
      encoder readings; None when not recorded;
    * ``flags``, ``message`` (why a flag was raised), ``meta`` (plan name, wall time, lab name; never hidden truth).

    A task's lab may return a subclass with more fields (``TASK`` names the task; ``SUMMARY_COLUMNS``,
    :meth:`summary_row`, :meth:`result_dict` and :meth:`result_kwargs` say how the log writes and reads them;
    ``ARRAY_FIELDS`` its arrays in :meth:`to_dict`; :meth:`write_files` and :meth:`read_files` its own files in a
    log's trial folder).
    """

    #: The task whose measurement this is; None: the touchdown measurement of log format version 1.
    TASK: ClassVar[str | None] = None
    #: The columns of trials.csv between ``plan_hash`` and ``flags``.
    SUMMARY_COLUMNS: ClassVar[tuple[str, ...]] = ("touchdown_x", "touchdown_y")
    #: The array fields :meth:`to_dict` writes (NaN as null) and :meth:`from_dict` reads, in this order.
    ARRAY_FIELDS: ClassVar[tuple[str, ...]] = ("joint_t", "q_commanded", "q_measured")

    trial: int
    plan: MotionPlan
    touchdown: np.ndarray | None = None
    joint_t: np.ndarray | None = None
    q_commanded: np.ndarray | None = None
    q_measured: np.ndarray | None = None
    flags: dict[str, bool] = field(default_factory=dict)
    message: str = ""
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> "Measurement":
        """Check types and shapes; raise :class:`MeasurementError` naming the problem. Returns self."""
        if isinstance(self.trial, bool) or not isinstance(self.trial, (int, np.integer)) or self.trial < 0:
            raise MeasurementError(f"measurement trial must be a non-negative integer, got {self.trial!r}")
        self.trial = int(self.trial)
        if not isinstance(self.plan, MotionPlan):
            raise MeasurementError(f"measurement plan must be a MotionPlan, got {type(self.plan).__name__}")
        td = _arr(self.touchdown, "touchdown", None)
        if td is not None and (td.shape != (2,) or not np.all(np.isfinite(td))):
            raise MeasurementError(f"measurement touchdown must be 2 finite numbers (x, y) in m, got {self.touchdown!r}")
        self.touchdown = td
        self.joint_t = _arr(self.joint_t, "joint_t", None)
        n_joints = self.plan.q.shape[1] if self.plan.q.ndim == 2 else 0
        self.q_commanded = _arr(self.q_commanded, "q_commanded", n_joints)
        self.q_measured = _arr(self.q_measured, "q_measured", n_joints)
        present = [x is not None for x in (self.joint_t, self.q_commanded, self.q_measured)]
        if any(present) and not all(present):
            raise MeasurementError("measurement joint_t, q_commanded and q_measured must all be given or all be None")
        if self.joint_t is not None and not (len(self.joint_t) == len(self.q_commanded) == len(self.q_measured)):
            raise MeasurementError(
                f"measurement joint arrays disagree in length: joint_t {len(self.joint_t)}, "
                f"q_commanded {len(self.q_commanded)}, q_measured {len(self.q_measured)}"
            )
        if self.joint_t is not None and not np.all(np.isfinite(self.joint_t)):
            raise MeasurementError("measurement joint_t contains NaN or inf")
        if not isinstance(self.flags, dict):
            raise MeasurementError(f"measurement flags must be a dict of booleans, got {type(self.flags).__name__}")
        self.flags = {str(k): bool(v) for k, v in self.flags.items()}
        self.message = str(self.message or "")
        if not isinstance(self.meta, dict):
            raise MeasurementError(f"measurement meta must be a dict, got {type(self.meta).__name__}")
        return self

    # ------------------------------------------------------------------ views
    @property
    def raised_flags(self) -> list[str]:
        """Names of the raised flags, sorted."""
        return sorted(k for k, v in self.flags.items() if v)

    @property
    def ok(self) -> bool:
        """True when a touchdown was measured and no flag is raised."""
        return self.touchdown is not None and not self.raised_flags

    def summary_row(self) -> dict[str, str]:
        """This trial's values of :attr:`SUMMARY_COLUMNS` for trials.csv (full precision, empty when not measured)."""
        td = self.touchdown
        return {"touchdown_x": "" if td is None else repr(float(td[0])), "touchdown_y": "" if td is None else repr(float(td[1]))}

    def progress_text(self) -> str:
        """One line about what was measured (``besdrake lab run`` prints it per trial)."""
        td = "not measured" if self.touchdown is None else f"({self.touchdown[0]:.3f}, {self.touchdown[1]:.3f}) m"
        return f"touchdown {td}, flags {','.join(self.raised_flags) or '-'}"

    def result_dict(self) -> dict[str, Any]:
        """A subclass's own fields, JSON-ready, merged into :meth:`to_dict` (none here)."""
        return {}

    @classmethod
    def result_kwargs(cls, d: dict[str, Any]) -> dict[str, Any]:
        """Constructor arguments of a subclass's own fields from a :meth:`to_dict` mapping (none here)."""
        return {}

    def write_files(self, folder, info: dict[str, Any]) -> None:
        """Write a subclass's own files into a log's trial ``folder`` and say so in ``info`` (its measurement.json,
        written after this); none here. Raise ``LogError`` for what cannot be written."""

    @classmethod
    def read_files(cls, folder, info: dict[str, Any]) -> dict[str, Any]:
        """Constructor arguments of a subclass's own files in a log's trial ``folder`` (``info``: its
        measurement.json); none here. Raise ``LogError`` for a missing or corrupt file."""
        return {}

    @property
    def plan_hash(self) -> str:
        """Content hash of the plan (see :func:`plan_hash`)."""
        return plan_hash(self.plan)

    # ------------------------------------------------------------------ JSON
    def to_dict(self, arrays: bool = True) -> dict[str, Any]:
        """JSON-ready dict; ``arrays=False`` leaves out the plan and the trajectories (the small parts only)."""

        def lst(x):
            return None if x is None else np.asarray(x).tolist()

        d: dict[str, Any] = {
            "trial": self.trial,
            "plan_hash": self.plan_hash,
            "touchdown": lst(self.touchdown),
            "flags": dict(self.flags),
            "message": self.message,
            "meta": dict(self.meta),
            **self.result_dict(),
        }
        if arrays:
            d["plan"] = self.plan.to_dict()
            for name in self.ARRAY_FIELDS:
                a = getattr(self, name)
                # NaN (marker gaps) is not JSON: write null.
                d[name] = None if a is None else np.where(np.isnan(a), None, a).tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any], plan: MotionPlan | None = None) -> "Measurement":
        """Inverse of :meth:`to_dict` (``plan`` replaces a missing ``"plan"`` entry).

        Raises :class:`MeasurementError` for missing keys or malformed values.
        """
        if not isinstance(d, dict):
            raise MeasurementError(f"a measurement must be a JSON object, got {type(d).__name__}")
        if "trial" not in d:
            raise MeasurementError("measurement is missing key 'trial'")
        if plan is None:
            if "plan" not in d:
                raise MeasurementError("measurement is missing key 'plan'")
            plan = MotionPlan.from_dict(d["plan"])

        def arr(name):
            v = d.get(name)
            if v is None:
                return None
            a = np.asarray(v, dtype=object)
            a = np.where(a == None, np.nan, a)  # noqa: E711 - null -> NaN
            return a.astype(float)

        m = cls(
            trial=d["trial"],
            plan=plan,
            touchdown=d.get("touchdown"),
            **{name: arr(name) for name in cls.ARRAY_FIELDS},
            flags=dict(d.get("flags") or {}),
            message=d.get("message", ""),
            meta=dict(d.get("meta") or {}),
            **cls.result_kwargs(d),
        )
        expected = d.get("plan_hash")
        if expected is not None and expected != m.plan_hash:
            raise MeasurementError(f"measurement of trial {m.trial}: plan_hash {expected} does not match its plan ({m.plan_hash})")
        return m


__all__ = ["FLAG_NAMES", "Measurement", "MeasurementError", "plan_hash"]
