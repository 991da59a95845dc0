"""The measured-data log: a documented, versioned folder a real lab could write (see ``LOG_FORMAT.md``).

::

    LOGDIR/
      log.json                          format, version, lab (public description), created, units, run
      trials.csv                        one row per trial (the commit marker), appended and fsync'ed
      trials/000007/plan.json           the MotionPlan
      trials/000007/measurement.json    touchdown, flags, message, meta, what was recorded
      trials/000007/joints.csv          t, q_cmd_joint1..6, q_meas_joint1..6 (when recorded)
      trials/000007/...                 the task's own files (its Measurement's write_files, e.g. a marker's TSV)

:meth:`LabLog.append` writes the trial folder first and the CSV row last, each file fsync'ed: a trial
exists once its row does. A folder without a row (a run killed while writing) is overwritten by the
next append; a row cut short by a kill (no final newline) is ignored by readers and cut off by the next
append (readers never modify the folder, so a log may be read while it is being written).
"""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

import numpy as np

from besdrake.plan import MotionPlan, PlanError
from besdrake.transfer.measurement import Measurement, MeasurementError

LOG_FORMAT = "besdrake-lab-log"
LOG_VERSION = 1
#: Version of a log whose trials hold a task's measurement (``log.json`` names the ``task``; see LOG_FORMAT.md).
TASK_LOG_VERSION = 2
SUPPORTED_VERSIONS = (LOG_VERSION, TASK_LOG_VERSION)
CSV_COLUMNS = ("trial", "plan_hash", "touchdown_x", "touchdown_y", "flags", "message")


def csv_columns(measurement_type: type[Measurement] = Measurement) -> tuple[str, ...]:
    """Header of trials.csv for logs of ``measurement_type`` (:data:`CSV_COLUMNS` for the touchdown measurement)."""
    return ("trial", "plan_hash", *measurement_type.SUMMARY_COLUMNS, "flags", "message")


def measurement_type_of(header: dict[str, Any], where: Path | str = "log.json") -> type[Measurement]:
    """The Measurement class of a log's trials: the default task's in a version-1 log, else its ``task``'s."""
    from besdrake.task import DEFAULT_TASK, TaskError, get_task

    if header.get("version") == LOG_VERSION:
        return get_task(DEFAULT_TASK).measurement_type()

    task = header.get("task")
    if not isinstance(task, str) or not task:
        raise LogError(f"{where}: a version {TASK_LOG_VERSION} log must name its task (\"task\": \"...\")")
    try:
        return get_task(task).measurement_type()
    except TaskError as err:
        raise LogError(f"{where}: {err}") from err


def joint_columns(plan: MotionPlan) -> tuple[str, ...]:
    """Header of joints.csv for ``plan``'s joints (named ``joint1``... when the plan carries no names)."""
    names = plan.joint_names or tuple(f"joint{k + 1}" for k in range(plan.q.shape[1]))
    return ("t", *(f"q_cmd_{n}" for n in names), *(f"q_meas_{n}" for n in names))
#: Per-trial file of SHA-256 checksums of the trial's other files (written last, checked when read).
CHECKSUMS = "checksums.json"


#: Writer locks this process holds, by lock-file path (kept until the process ends).
_HELD_LOCKS: dict[Path, Any] = {}


class LogError(ValueError):
    """A log folder is missing, of another format or version, corrupt, or used inconsistently."""


def _fsync_write(path: Path, text: str) -> None:
    with open(path, "w", encoding="utf-8", newline="") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # pragma: no cover - platforms without directory fds
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover
        pass
    finally:
        os.close(fd)


def _trial_dir(root: Path, trial: int) -> Path:
    return root / "trials" / f"{trial:06d}"


def _fmt(x: float) -> str:
    return repr(float(x))


class LabLog:
    """An open measured-data log; create with :meth:`create`, reopen with :meth:`open`."""

    def __init__(self, root: Path, header: dict[str, Any], rows: list[dict[str, str]],
                 measurement_type: type[Measurement] = Measurement) -> None:
        self.root = root
        self.header = header
        self._rows = rows
        #: The Measurement class of this log's trials.
        self.measurement_type = measurement_type
        self._lock = None  # file object holding the writer's lock, taken on the first append

    def _take_writer_lock(self) -> None:
        """One writer per log: an exclusive ``flock`` on ``LOGDIR/.writer.lock`` (released when the process
        ends, also when it is killed). :class:`LogError` if another process holds it."""
        if self._lock is not None:
            return
        key = (self.root / ".writer.lock").resolve()
        if key in _HELD_LOCKS:  # this process already writes this log (e.g. a reopened LabLog)
            self._lock = _HELD_LOCKS[key]
            return
        f = open(key, "a+")
        try:
            import fcntl

            fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except ImportError:  # pragma: no cover - no flock (Windows): single writer by convention
            pass
        except OSError:
            f.close()
            raise LogError(f"another process is writing the log {self.root}") from None
        _HELD_LOCKS[key] = self._lock = f

    # ------------------------------------------------------------------ open / create
    @classmethod
    def create(cls, logdir: str | Path, lab_description: dict[str, Any] | str, run: dict[str, Any] | None = None,
               measurement: type[Measurement] | None = None) -> "LabLog":
        """Start a new log in ``logdir`` (created; must not already hold a log or other files).

        ``lab_description``: the lab's public description (name, sensors; never hidden truth);
        ``run``: facts about the run to check on resume (e.g. the seed); ``measurement``: the class of the trials
        (a task's, e.g. a lab's ``measurement_type``: a version-2 log naming the task; None: the default task's, a
        version-1 log)."""
        if measurement is None:
            from besdrake.task import DEFAULT_TASK, get_task

            measurement = get_task(DEFAULT_TASK).measurement_type()
        if not (isinstance(measurement, type) and issubclass(measurement, Measurement)):
            raise LogError(f"measurement must be a Measurement class, got {measurement!r}")
        root = Path(logdir)
        if root.exists() and (not root.is_dir() or not cls._is_unfinished_create(root)):
            raise LogError(f"{root} already exists and is not an empty folder; open it with LabLog.open to resume")
        if isinstance(lab_description, str):
            lab_description = {"name": lab_description}
        if not isinstance(lab_description, dict) or not lab_description.get("name"):
            raise LogError("lab_description must be a dict with a non-empty 'name' (or a name string)")
        root.mkdir(parents=True, exist_ok=True)
        (root / "trials").mkdir(exist_ok=True)
        header = {
            "format": LOG_FORMAT,
            "version": LOG_VERSION if measurement.TASK is None else TASK_LOG_VERSION,
            **({} if measurement.TASK is None else {"task": measurement.TASK}),
            "lab": lab_description,
            "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "units": "SI (m, s, rad)",
            "run": dict(run or {}),
        }
        _fsync_write(root / "trials.csv", ",".join(csv_columns(measurement)) + "\n")
        _fsync_write(root / "log.json", json.dumps(header, indent=2) + "\n")
        _fsync_dir(root)
        return cls(root, header, [], measurement)

    @staticmethod
    def _is_unfinished_create(root: Path) -> bool:
        """True for an empty folder or one left by a :meth:`create` killed before log.json was written
        (at most an empty ``trials/`` and a header-only ``trials.csv``): it may be created again."""
        for p in root.iterdir():
            if p.name == ".writer.lock":
                continue
            if p.name == "trials" and p.is_dir() and not any(p.iterdir()):
                continue
            if p.name == "trials.csv" and p.is_file() and p.read_text(encoding="utf-8", errors="replace").count("\n") <= 1:
                continue
            return False
        return True

    @classmethod
    def open(cls, logdir: str | Path) -> "LabLog":
        """Open an existing log (for reading or to append more trials); :class:`LogError` if it is not one."""
        root = Path(logdir)
        if not root.is_dir():
            raise LogError(f"log folder not found: {root}")
        hp = root / "log.json"
        if not hp.is_file():
            raise LogError(f"{root} is not a besdrake lab log: no log.json")
        header = _load_json(hp)
        if not isinstance(header, dict) or header.get("format") != LOG_FORMAT:
            raise LogError(f"{hp}: format is {header.get('format') if isinstance(header, dict) else None!r}, expected {LOG_FORMAT!r}")
        if header.get("version") not in SUPPORTED_VERSIONS:
            raise LogError(f"{hp}: log format version {header.get('version')!r} is not supported (this reader knows versions "
                           f"{', '.join(map(str, SUPPORTED_VERSIONS))})")
        kind = measurement_type_of(header, hp)
        rows = cls._read_rows(root / "trials.csv", csv_columns(kind))
        return cls(root, header, rows, kind)

    @staticmethod
    def _read_rows(path: Path, columns: tuple[str, ...] = CSV_COLUMNS) -> list[dict[str, str]]:
        if not path.is_file():
            raise LogError(f"{path.parent} is not a complete log: trials.csv is missing")
        raw = path.read_bytes()
        # A last line without its newline is a row cut short by a kill (or being written right now): it has
        # not committed, so it is ignored here; the next append cuts it off (readers never modify the file).
        raw = raw[: raw.rfind(b"\n") + 1]
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as err:
            raise LogError(f"{path} is not UTF-8 text: {err}") from err
        reader = csv.reader(io.StringIO(text))
        try:
            head = next(reader)
        except StopIteration:
            raise LogError(f"{path} is empty (no header line)") from None
        if tuple(head) != columns:
            raise LogError(f"{path}: header {head} differs from the format's {list(columns)}")
        rows = []
        for k, fields in enumerate(reader):
            line = k + 2
            if len(fields) != len(columns):
                raise LogError(f"{path}, line {line}: {len(fields)} fields, expected {len(columns)}")
            row = dict(zip(columns, fields))
            if row["trial"] != str(k):
                raise LogError(f"{path}, line {line}: trial {row['trial']!r}, expected {k} (trials must be 0, 1, 2, ... without gaps)")
            rows.append(row)
        return rows

    # ------------------------------------------------------------------ access
    def __len__(self) -> int:
        return len(self._rows)

    @property
    def lab(self) -> dict[str, Any]:
        """The lab's public description from ``log.json``."""
        return dict(self.header.get("lab") or {})

    def rows(self) -> list[dict[str, str]]:
        """The rows of trials.csv (strings, as written), one per committed trial."""
        return [dict(r) for r in self._rows]

    def plan_hashes(self) -> list[str]:
        """The plan hash of every logged trial, in trial order (cheap: read from trials.csv)."""
        return [r["plan_hash"] for r in self._rows]

    def measurement(self, trial: int) -> Measurement:
        """Read trial ``trial`` back; :class:`LogError` naming the file when something is missing or corrupt."""
        if not 0 <= trial < len(self._rows):
            raise LogError(f"trial {trial} is not in the log {self.root} ({len(self._rows)} trials)")
        return read_trial(self.root, trial, expected_hash=self._rows[trial]["plan_hash"], measurement_type=self.measurement_type)

    def measurements(self) -> list[Measurement]:
        """All logged trials in order."""
        return [self.measurement(k) for k in range(len(self._rows))]

    # ------------------------------------------------------------------ append
    def append(self, m: Measurement) -> None:
        """Write ``m`` as the next trial: its folder first (each file fsync'ed), then its row in trials.csv.

        ``m.trial`` must equal ``len(self)``. A leftover folder of an interrupted write is replaced."""
        if not isinstance(m, Measurement):
            raise LogError(f"LabLog.append needs a Measurement, got {type(m).__name__}")
        m.validate()
        if type(m).TASK != self.measurement_type.TASK or type(m).SUMMARY_COLUMNS != self.measurement_type.SUMMARY_COLUMNS:
            raise LogError(f"cannot append a {type(m).__name__} to the log {self.root}: it holds "
                           f"{self.measurement_type.__name__} trials (task {self.measurement_type.TASK or 'of format version 1'})")
        self._take_writer_lock()
        if m.trial != len(self._rows):
            raise LogError(f"cannot append trial {m.trial}: the log {self.root} holds {len(self._rows)} trials, so the next is {len(self._rows)}")
        d = _trial_dir(self.root, m.trial)
        if d.exists():
            shutil.rmtree(d)  # an uncommitted (interrupted) write of this trial
        tmp = d.with_name(d.name + ".tmp")
        if tmp.exists():
            shutil.rmtree(tmp)
        tmp.mkdir(parents=True)
        write_trial_files(tmp, m)
        _fsync_dir(tmp)
        os.replace(tmp, d)
        _fsync_dir(d.parent)
        row = self._row(m)
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerow([row[c] for c in csv_columns(self.measurement_type)])
        with open(self.root / "trials.csv", "r+b") as f:
            size = f.seek(0, os.SEEK_END)
            f.seek(max(size - 4096, 0))
            tail = f.read()
            if tail and not tail.endswith(b"\n"):  # drop an uncommitted partial row left by a kill
                cut = tail.rfind(b"\n")
                if cut < 0:
                    raise LogError(f"{self.root / 'trials.csv'}: cannot find the end of the last complete row")
                f.truncate(size - len(tail) + cut + 1)
            f.seek(0, os.SEEK_END)
            f.write(buf.getvalue().encode("utf-8"))
            f.flush()
            os.fsync(f.fileno())
        self._rows.append(row)

    @staticmethod
    def _row(m: Measurement) -> dict[str, str]:
        return {
            "trial": str(m.trial),
            "plan_hash": m.plan_hash,
            **m.summary_row(),
            "flags": ";".join(m.raised_flags),
            "message": " ".join(m.message.split()),  # one line; the full text is in measurement.json
        }


# ---------------------------------------------------------------------------------------- trial files


def write_trial_files(folder: Path, m: Measurement) -> None:
    """Write the files of one trial into ``folder`` (plan.json, measurement.json, joints.csv, the measurement's own)."""
    _fsync_write(folder / "plan.json", json.dumps(m.plan.to_dict()) + "\n")
    info: dict[str, Any] = m.to_dict(arrays=False)
    info["joints_recorded"] = m.joint_t is not None
    if m.joint_t is not None:
        data = np.column_stack([m.joint_t, m.q_commanded, m.q_measured])
        lines = [",".join(joint_columns(m.plan))] + [",".join(_fmt(x) for x in row) for row in data]
        _fsync_write(folder / "joints.csv", "\n".join(lines) + "\n")
    m.write_files(folder, info)
    _fsync_write(folder / "measurement.json", json.dumps(info, indent=1) + "\n")
    sums = {f.name: _sha256(f) for f in sorted(folder.iterdir()) if f.is_file() and f.name != CHECKSUMS}
    _fsync_write(folder / CHECKSUMS, json.dumps(sums, indent=1) + "\n")


def _sha256(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()


def verify_trial(root: str | Path, trial: int) -> None:
    """:class:`LogError` when a committed trial's folder is missing or a file in it differs from the
    checksum written with it (edited by hand, damaged); logs written before checksums pass when present."""
    d = _trial_dir(Path(root), trial)
    if not d.is_dir():
        raise LogError(f"trial {trial} is in trials.csv but its folder {d} is missing: the log is damaged; "
                       "restore the folder or start a new log")
    path = d / CHECKSUMS
    if not path.is_file():
        return
    sums = _load_json(path)
    if not isinstance(sums, dict):
        raise LogError(f"{path}: not a mapping of file names to SHA-256 checksums")
    for name, digest in sums.items():
        f = d / str(name)
        if not f.is_file():
            raise LogError(f"{f} is missing (the trial was written with it): the log is damaged")
        if _sha256(f) != digest:
            raise LogError(f"{f} was changed after the trial was logged (its SHA-256 differs from {CHECKSUMS}): "
                           "a log records what was measured; restore the file or start a new log")


def _load_json(path: Path) -> Any:
    if not path.is_file():
        raise LogError(f"log file missing: {path}")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise LogError(f"{path} is not valid JSON: {err}") from err


def read_trial(root: str | Path, trial: int, expected_hash: str | None = None,
               measurement_type: type[Measurement] | None = None) -> Measurement:
    """Read one committed trial folder of the log at ``root`` (as ``measurement_type``; None: the log's)."""
    if measurement_type is None:
        measurement_type = measurement_type_of(_load_json(Path(root) / "log.json"), Path(root) / "log.json")
    d = _trial_dir(Path(root), trial)
    verify_trial(root, trial)
    info = _load_json(d / "measurement.json")
    plan_d = _load_json(d / "plan.json")
    try:
        plan = MotionPlan.from_dict(plan_d)
    except PlanError as err:
        if not (info.get("flags") or {}).get("refused_by_safety_gate"):
            raise LogError(f"{d / 'plan.json'}: {err}") from err
        # A malformed plan that the gate refused: keep it as written.
        plan = MotionPlan(t=plan_d.get("t", []), q=plan_d.get("q", []), qd=plan_d.get("qd"), meta=dict(plan_d.get("meta") or {}))
    joint_t = q_cmd = q_meas = None
    if info.get("joints_recorded"):
        path = d / "joints.csv"
        if not path.is_file():
            raise LogError(f"log file missing: {path} (measurement.json says joints were recorded)")
        lines = path.read_text(encoding="utf-8").splitlines()
        columns = joint_columns(plan)
        if not lines or tuple(lines[0].split(",")) != columns:
            raise LogError(f"{path}: header must be {','.join(columns)}")
        n = plan.q.shape[1]
        try:
            data = np.array([[float(x) for x in ln.split(",")] for ln in lines[1:] if ln.strip()], dtype=float).reshape(-1, len(columns))
        except ValueError as err:
            raise LogError(f"{path}: not numeric or wrong number of columns: {err}") from err
        joint_t, q_cmd, q_meas = data[:, 0], data[:, 1 : 1 + n], data[:, 1 + n : 1 + 2 * n]
    try:
        m = measurement_type(
            trial=int(info.get("trial", trial)),
            plan=plan,
            touchdown=info.get("touchdown"),
            joint_t=joint_t,
            q_commanded=q_cmd,
            q_measured=q_meas,
            flags=dict(info.get("flags") or {}),
            message=info.get("message", ""),
            meta=dict(info.get("meta") or {}),
            **measurement_type.result_kwargs(info),
            **measurement_type.read_files(d, info),
        )
    except MeasurementError as err:
        raise LogError(f"{d}: {err}") from err
    if m.trial != trial:
        raise LogError(f"{d / 'measurement.json'}: says trial {m.trial}, expected {trial}")
    if expected_hash is not None and m.plan_hash != expected_hash:
        raise LogError(f"{d / 'plan.json'}: plan hash {m.plan_hash} differs from trials.csv's {expected_hash}")
    return m


def read_log(logdir: str | Path) -> list[Measurement]:
    """All trials of the log at ``logdir``, in order."""
    return LabLog.open(logdir).measurements()




# ---------------------------------------------------------------------------------------- filling a log


@dataclass
class RunSummary:
    """What :func:`run_plans` did: trials already in the log (skipped), executed now, and the log's total."""

    skipped: int
    executed: int
    total: int
    flag_counts: dict[str, int]


def run_plans(lab: Any, plans: list[MotionPlan], log: LabLog, progress: Callable[[Measurement], None] | None = None) -> RunSummary:
    """Execute ``plans`` through ``lab`` as trials 0, 1, ... and append each to ``log`` before the next runs.

    Resumes an interrupted run: the trials already in the log are skipped after checking that they are the
    same plans (:class:`LogError` otherwise), so no trial is repeated or lost. ``lab`` must make trial ``k``
    reproducible (the interrupted trial is executed again from scratch)."""
    from besdrake.transfer.measurement import plan_hash

    done = log.plan_hashes()
    if len(done) > len(plans):
        raise LogError(f"the log {log.root} holds {len(done)} trials but only {len(plans)} plans were given: not the same run")
    for k, h in enumerate(done):
        verify_trial(log.root, k)
        if plan_hash(plans[k]) != h:
            raise LogError(
                f"trial {k} in the log {log.root} executed a different plan than plan {k} given now "
                f"({h[:12]}... vs {plan_hash(plans[k])[:12]}...): not the same run; use a new log folder"
            )
    flag_counts: dict[str, int] = {}
    for k in range(len(done), len(plans)):
        m = lab.execute(plans[k], trial=k)
        if m.trial != k:
            raise LogError(f"the lab returned trial {m.trial} for trial {k}")
        log.append(m)
        for f in m.raised_flags:
            flag_counts[f] = flag_counts.get(f, 0) + 1
        if progress is not None:
            progress(m)
    return RunSummary(skipped=len(done), executed=len(plans) - len(done), total=len(log), flag_counts=flag_counts)


__all__ = ["LabLog", "LogError", "RunSummary", "run_plans", "read_log", "read_trial", "write_trial_files", "verify_trial", "LOG_FORMAT",
           "LOG_VERSION", "TASK_LOG_VERSION", "CSV_COLUMNS", "csv_columns", "joint_columns", "measurement_type_of"]
