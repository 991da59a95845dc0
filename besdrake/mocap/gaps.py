"""Gap filling for labelled marker trajectories.

Short gaps of a marker on a rigid plate (three markers with fixed distances) are filled by a
rigid fit: the missing marker keeps its learned distances to the two visible plate markers and
its rotation about their axis is interpolated between the gap's edges. Other short gaps get a
cubic spline through a few samples on each side. Gaps longer than ``max_gap_s``, gaps at the
start or end of the recording and markers that are never visible are left as NaN and flagged.
"""

from __future__ import annotations

import warnings

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline

from besdrake.mocap.recording import MocapRecording


@dataclass(frozen=True)
class GapInfo:
    """One run of missing samples of one marker (frame numbers inclusive, file numbering)."""

    marker: str
    start_frame: int
    end_frame: int
    n_frames: int
    method: str  # "rigid", "spline", "linear" or "none"
    reason: str = ""  # why it was not filled: "too long", "at edge", "never visible"

    @property
    def filled(self) -> bool:
        return self.method != "none"


@dataclass
class GapFillResult:
    recording: MocapRecording
    gaps: list[GapInfo] = field(default_factory=list)
    filled_mask: np.ndarray = None  # type: ignore[assignment]  (n_frames, n_markers) True where filled

    @property
    def flagged(self) -> list[GapInfo]:
        return [g for g in self.gaps if not g.filled]


def find_gaps(visible: np.ndarray) -> list[tuple[int, int, int]]:
    """Runs of False per column: ``(column, first_row, end_row_exclusive)``."""
    out = []
    for col in range(visible.shape[1]):
        v = np.concatenate([[True], visible[:, col], [True]]).astype(int)
        starts = np.nonzero(np.diff(v) == -1)[0]
        ends = np.nonzero(np.diff(v) == 1)[0]
        out += [(col, int(a), int(b)) for a, b in zip(starts, ends)]
    return out


def _axis_frame(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit axis a->b and two perpendicular unit vectors (vectorised over rows)."""
    e1 = (b - a) / np.linalg.norm(b - a, axis=1, keepdims=True)
    ref = np.where(np.abs(e1[:, 2:3]) < 0.9, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))
    u = ref - np.sum(ref * e1, axis=1, keepdims=True) * e1
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    w = np.cross(e1, u)
    return e1, u, w


def _rigid_fill(pos: np.ndarray, c: int, a_idx: int, b_idx: int, g0: int, g1: int) -> np.ndarray | None:
    """Fill rows g0..g1-1 (an inner gap) of marker ``c`` from plate partners ``a_idx``, ``b_idx``; None if impossible."""
    rows = np.arange(g0 - 1, g1 + 1)  # an inner gap and its two edge samples (fill_gaps skips edge gaps)
    pa, pb, pc = pos[rows, a_idx], pos[rows, b_idx], pos[rows, c]
    if np.isnan(pa).any() or np.isnan(pb).any():
        return None
    vis = ~np.isnan(pos[:, [a_idx, b_idx, c]]).any(axis=2).any(axis=1)
    if vis.sum() < 3:
        return None
    d_ab = np.median(np.linalg.norm(pos[vis, a_idx] - pos[vis, b_idx], axis=1))
    d_ac = np.median(np.linalg.norm(pos[vis, a_idx] - pos[vis, c], axis=1))
    d_bc = np.median(np.linalg.norm(pos[vis, b_idx] - pos[vis, c], axis=1))
    along = (d_ac**2 - d_bc**2 + d_ab**2) / (2 * d_ab)
    radius = np.sqrt(max(d_ac**2 - along**2, 0.0))
    e1, u, w = _axis_frame(pa, pb)
    rel = pc[[0, -1]] - pa[[0, -1]]
    theta_edges = np.arctan2(np.sum(rel * w[[0, -1]], axis=1), np.sum(rel * u[[0, -1]], axis=1))
    theta_edges[1] = theta_edges[0] + np.angle(np.exp(1j * (theta_edges[1] - theta_edges[0])))
    s = np.linspace(0.0, 1.0, len(rows))
    theta = theta_edges[0] + s * (theta_edges[1] - theta_edges[0])
    filled = pa + along * e1 + radius * (np.cos(theta)[:, None] * u + np.sin(theta)[:, None] * w)
    return filled[1:-1]


def _spline_fill(t: np.ndarray, x: np.ndarray, g0: int, g1: int, context: int = 5) -> tuple[np.ndarray, str]:
    """Values for rows g0..g1-1 of ``x`` (an inner gap: 0 < g0, g1 < len(x)) and the method used."""
    n = len(x)
    lo = [i for i in range(g0 - 1, max(-1, g0 - 1 - context), -1) if not np.isnan(x[i]).any()]
    hi = [i for i in range(g1, min(n, g1 + context)) if not np.isnan(x[i]).any()]
    # Only use the contiguous visible run next to the gap.
    lo = [i for k, i in enumerate(lo) if i == g0 - 1 - k]
    hi = [i for k, i in enumerate(hi) if i == g1 + k]
    idx = sorted(lo) + hi
    rows = np.arange(g0, g1)
    if len(lo) >= 2 and len(hi) >= 2:
        return CubicSpline(t[idx], x[idx], axis=0)(t[rows]), "spline"
    s = (t[rows] - t[g0 - 1]) / (t[g1] - t[g0 - 1])
    return x[g0 - 1] + s[:, None] * (x[g1] - x[g0 - 1]), "linear"


#: A sample farther than this (metres) from the median of its +-3 neighbours is a glitch. The median of a
#: smoothly moving marker's window is the sample itself whatever the speed, so only jumps count.
OUTLIER_OFFSET_M = 0.5


def reject_outliers(rec: MocapRecording, max_offset_m: float = OUTLIER_OFFSET_M, half_window: int = 3) -> tuple[MocapRecording, list[str]]:
    """A copy of ``rec`` with single glitch samples (at most ``half_window`` in a row, farther than
    ``max_offset_m`` from the median of their neighbours) set missing, and one warning per marker."""
    out = rec.copy()
    pos = out.positions
    n = rec.n_frames
    if n < 2 * half_window + 1:
        return out, []
    pad = np.full((half_window, rec.n_markers, 3), np.nan)
    windows = np.lib.stride_tricks.sliding_window_view(np.concatenate([pad, pos, pad]), 2 * half_window + 1, axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN windows
        med = np.nanmedian(windows, axis=-1)
    offset = np.linalg.norm(pos - med, axis=2)
    bad = np.isfinite(offset) & (offset > max_offset_m)
    messages = []
    for j in np.nonzero(bad.any(axis=0))[0]:
        frames = rec.frames[bad[:, j]]
        pos[bad[:, j], j] = np.nan
        shown = ", ".join(str(int(f)) for f in frames[:5]) + (", ..." if len(frames) > 5 else "")
        messages.append(f"{rec.marker_names[j]}: {len(frames)} sample(s) more than {max_offset_m:g} m off their neighbours "
                        f"rejected as glitches (frame {shown})")
    return out, messages


def fill_gaps(rec: MocapRecording, max_gap_s: float = 0.25, plates: list[list[str]] | None = None) -> GapFillResult:
    """Fill short gaps (at most ``max_gap_s`` long) of ``rec``; return a new recording and a report.

    ``plates`` lists rigid marker triples (names); a missing plate marker whose two partners are
    visible across the gap is filled by a rigid fit, everything else by a cubic spline.
    """
    if not np.isfinite(max_gap_s) or max_gap_s < 0:
        raise ValueError(f"max_gap_s must be a number of seconds >= 0, got {max_gap_s}")
    out = rec.copy()
    pos = out.positions
    vis = rec.visible()
    filled = np.zeros(vis.shape, dtype=bool)
    partners: dict[int, tuple[int, int]] = {}
    for plate in plates or []:
        idx = [rec.marker_index(n) for n in plate[:3]]
        if len(idx) == 3:
            for k in range(3):
                partners[idx[k]] = (idx[(k + 1) % 3], idx[(k + 2) % 3])
    max_len = int(round(max_gap_s * rec.frequency))
    report: list[GapInfo] = []
    for col, g0, g1 in find_gaps(vis):
        name = rec.marker_names[col]
        f0, f1 = int(rec.frames[g0]), int(rec.frames[g1 - 1])
        length = g1 - g0
        if not vis[:, col].any():
            report.append(GapInfo(name, f0, f1, length, "none", "never visible"))
            continue
        if g0 == 0 or g1 >= rec.n_frames:
            report.append(GapInfo(name, f0, f1, length, "none", "at edge"))
            continue
        if length > max_len:
            report.append(GapInfo(name, f0, f1, length, "none", "too long"))
            continue
        values, method = None, ""
        if col in partners:
            values = _rigid_fill(rec.positions, col, *partners[col], g0, g1)
            method = "rigid"
        if values is None:
            values, method = _spline_fill(rec.time, rec.positions[:, col], g0, g1)
        pos[g0:g1, col] = values
        filled[g0:g1, col] = True
        report.append(GapInfo(name, f0, f1, length, method))
    return GapFillResult(out, report, filled)
