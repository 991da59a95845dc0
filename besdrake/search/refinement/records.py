"""Refinement's episode records: one :class:`RewardBreakdown` per episode, keyed by :func:`params_key`, appended to
``details.csv`` (:func:`read_details` reads them back when a run resumes)."""

from __future__ import annotations

import csv
import hashlib
import os
from pathlib import Path

import numpy as np

from besdrake.search.refinement.settings import RefinementError
from besdrake.search.reward import RewardBreakdown, failed_breakdown

__all__ = ["RewardBreakdown", "failed_breakdown", "params_key", "read_details"]

def params_key(x: np.ndarray) -> str:
    """Identifier of a candidate (its exact float values), to join episode records."""
    return hashlib.sha1(np.ascontiguousarray(np.asarray(x, dtype=float).ravel()).tobytes()).hexdigest()[:16]


_DETAIL_COLUMNS = ["key", "reward", "distance", "penalty", "touchdown_x", "touchdown_y", "flags", "message"]
#: written where a run checks robustness (:mod:`besdrake.search.refinement.robust`): one column more
_ROBUST_COLUMNS = _DETAIL_COLUMNS + ["robust_distance", "robust_rollouts"]


def _details_row(key: str, r: RewardBreakdown, robust: bool = False) -> list[str]:
    td = r.touchdown if r.touchdown is not None else (np.nan, np.nan)
    row = [key, repr(float(r.reward)), repr(float(r.distance)), repr(float(r.penalty)), repr(float(td[0])), repr(float(td[1])), ";".join(r.flags), r.message.replace("\n", " ")[:300]]
    return row + [repr(float(r.robust_distance)), str(int(r.robust_rollouts))] if robust else row


def _append_details(path: Path, rows: list[list[str]], robust: bool = False) -> None:
    new = not path.exists() or path.stat().st_size == 0
    with open(path, "a", newline="") as handle:
        writer = csv.writer(handle)
        if new:
            writer.writerow(_ROBUST_COLUMNS if robust else _DETAIL_COLUMNS)
        writer.writerows(rows)
        handle.flush()
        os.fsync(handle.fileno())


def read_details(path: Path) -> dict[str, RewardBreakdown]:
    """Episode records written during a run, by :func:`params_key` (a truncated last row is skipped)."""
    out: dict[str, RewardBreakdown] = {}
    if not path.exists():
        return out
    with open(path, newline="") as handle:
        reader = csv.reader(handle)
        header = next(reader, None)
        if header not in (_DETAIL_COLUMNS, _ROBUST_COLUMNS):
            raise RefinementError(f"{path}: not a refinement details file (columns {header})")
        for fields in reader:
            if len(fields) != len(header):
                continue
            try:
                tx, ty = float(fields[4]), float(fields[5])
                out[fields[0]] = RewardBreakdown(
                    float(fields[1]), float(fields[2]), float(fields[3]),
                    None if not (np.isfinite(tx) and np.isfinite(ty)) else (tx, ty),
                    [f for f in fields[6].split(";") if f], fields[7],
                    robust_distance=float(fields[8]) if len(fields) > 8 else float("nan"),
                    robust_rollouts=int(fields[9]) if len(fields) > 9 else 0,
                )
            except ValueError:
                continue
    return out
