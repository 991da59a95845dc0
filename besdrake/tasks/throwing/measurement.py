"""What a throwing lab measures for one trial: :class:`ThrowMeasurement`, a
:class:`~besdrake.transfer.measurement.Measurement` (touchdown, encoder log, flags) plus the ball marker's path.

Flags besides the general ones: ``ball_not_seen`` (the touchdown was not seen by motion capture: outside the capture
volume), ``dropped_early`` (the ball fell out of the scoop rather than being thrown), ``never_released`` (the ball
stayed in the scoop). Positions in the world frame, throws go +x.

In a log (format version 1: the throwing task's, ``LOG_FORMAT.md``) a trial's ball marker is ``ball.tsv`` (Qualisys
TSV, marker ``ball``, mm) and its measurement.json says ``ball_recorded``, ``ball_samples`` and the exact ``ball_t``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from besdrake.transfer.measurement import FLAG_NAMES as GENERAL_FLAGS
from besdrake.transfer.measurement import Measurement, MeasurementError, _arr

#: Flags a throwing lab may raise.
FLAG_NAMES: tuple[str, ...] = (
    "refused_by_safety_gate",
    "ball_not_seen",
    "dropped_early",
    "never_released",
    "joint_limit_exceeded",
    "aborted",
)
assert set(GENERAL_FLAGS) <= set(FLAG_NAMES)
#: The marker name in ball.tsv.
BALL_MARKER = "ball"
#: Frequency written into ball.tsv when a lab records the ball at irregular times (see LOG_FORMAT.md).
DEFAULT_BALL_RATE_HZ = 100.0


@dataclass(kw_only=True)
class ThrowMeasurement(Measurement):
    """One throw as a lab measured it: besides the :class:`Measurement` fields, ``ball_t`` (M,) s since plan start
    and ``ball_path`` (M, 3) m: the ball marker while inside the capture volume (NaN rows = marker not seen in that
    frame); None when the lab does not record it."""

    ARRAY_FIELDS: ClassVar[tuple[str, ...]] = ("ball_t", "ball_path", "joint_t", "q_commanded", "q_measured")

    ball_t: np.ndarray | None = None
    ball_path: np.ndarray | None = None

    def validate(self) -> "ThrowMeasurement":
        super().validate()
        self.ball_t = _arr(self.ball_t, "ball_t", None)
        self.ball_path = _arr(self.ball_path, "ball_path", 3)
        if (self.ball_t is None) != (self.ball_path is None):
            raise MeasurementError("measurement ball_t and ball_path must both be given or both be None")
        if self.ball_t is not None and len(self.ball_t) != len(self.ball_path):
            raise MeasurementError(f"measurement ball_t has {len(self.ball_t)} samples but ball_path {len(self.ball_path)}")
        if self.ball_t is not None and not np.all(np.isfinite(self.ball_t)):
            raise MeasurementError("measurement ball_t contains NaN or inf")
        return self

    def write_files(self, folder: Path, info: dict[str, Any]) -> None:
        """``ball.tsv`` (when the ball was recorded and seen) and ``ball_recorded``/``ball_samples``/``ball_t``."""
        from besdrake.mocap.qualisys import write_tsv
        from besdrake.mocap.recording import MocapRecording
        from besdrake.transfer.log import LogError

        info["ball_recorded"] = self.ball_t is not None
        if self.ball_t is None or not len(self.ball_t):
            return
        rate = float(self.meta.get("mocap_rate_hz") or DEFAULT_BALL_RATE_HZ)
        frames = np.rint(self.ball_t * rate).astype(int) + 1
        if np.any(np.diff(frames) <= 0) or np.any(frames < 1):
            raise LogError(
                f"trial {self.trial}: ball_t is not on a {rate:g} Hz grid from the plan start (frames must increase); "
                "set meta['mocap_rate_hz'] to the capture rate"
            )
        rec = MocapRecording([BALL_MARKER], self.ball_path[:, None, :], rate, frames=frames, time=self.ball_t,
                             metadata={"DESCRIPTION": f"besdrake lab log trial {self.trial}: ball marker, time from plan start"})
        tmp = Path(folder) / "ball.tsv"
        write_tsv(rec, tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        info["ball_samples"] = int(len(self.ball_t))
        info["ball_t"] = self.ball_t.tolist()  # exact times (the TSV's Time column has 10 us resolution)

    @classmethod
    def read_files(cls, folder: Path, info: dict[str, Any]) -> dict[str, Any]:
        """``ball_t`` and ``ball_path`` from ``ball.tsv`` (None when not recorded)."""
        from besdrake.mocap.qualisys import read_tsv
        from besdrake.mocap.recording import MocapFormatError
        from besdrake.transfer.log import LogError

        if not info.get("ball_recorded"):
            return {"ball_t": None, "ball_path": None}
        n = int(info.get("ball_samples", 0))
        if n == 0:
            return {"ball_t": np.zeros(0), "ball_path": np.zeros((0, 3))}
        path = Path(folder) / "ball.tsv"
        if not path.is_file():
            raise LogError(f"log file missing: {path} (measurement.json says {n} ball samples)")
        try:
            rec = read_tsv(path, check_units=False)
        except MocapFormatError as err:
            raise LogError(f"{path}: {err}") from err
        if BALL_MARKER not in rec.marker_names or rec.n_frames != n:
            raise LogError(f"{path}: expected marker {BALL_MARKER!r} with {n} frames, got {rec.marker_names} with {rec.n_frames}")
        ball_t = np.asarray(info["ball_t"], float) if info.get("ball_t") is not None else rec.time
        return {"ball_t": ball_t, "ball_path": rec.marker(BALL_MARKER)}


__all__ = ["BALL_MARKER", "DEFAULT_BALL_RATE_HZ", "FLAG_NAMES", "ThrowMeasurement"]
