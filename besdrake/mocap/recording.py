"""The in-memory motion-capture recording shared by all readers and writers.

Positions are stored in metres (SI); file readers convert at the boundary.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


class MocapFormatError(ValueError):
    """A motion-capture file (or recording) that cannot be read or is implausible.

    The message names the file and, where it applies, the line.
    """


class MocapUnitsError(MocapFormatError):
    """Positions whose spatial extent does not fit a human in a capture volume (wrong units?)."""


#: Plausible spatial extent (metres) of the visible markers of one human recording.
MIN_PLAUSIBLE_EXTENT_M = 0.02
MAX_PLAUSIBLE_EXTENT_M = 50.0
#: The rigid marker plates (back and hand) by marker name, and the range their edges may have (metres):
#: 28-65 mm on the real recordings and the synthetic demonstrator; a file whose plate edges are 10x
#: shorter is in centimetres, not millimetres.
PLATES = (("Back top", "Back right", "Back left"), ("Hand top", "Hand right", "Hand left"))
PLATE_EDGE_RANGE_M = (0.01, 0.2)


@dataclass
class MocapRecording:
    """Marker trajectories of one motion-capture recording.

    Attributes:
        marker_names: one name per marker, unique.
        positions: ``(n_frames, n_markers, 3)`` in metres, NaN where a marker is missing.
        frequency: sampling rate in Hz.
        frames: ``(n_frames,)`` int, the file's own frame numbering (1-based in Qualisys;
            cropped exports start later).
        time: ``(n_frames,)`` seconds.
        metadata: header keys (strings) kept for writing the file back.
    """

    marker_names: list[str]
    positions: np.ndarray
    frequency: float
    frames: np.ndarray = None  # type: ignore[assignment]
    time: np.ndarray = None  # type: ignore[assignment]
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.marker_names = [str(n) for n in self.marker_names]
        self.positions = np.asarray(self.positions, dtype=float)
        if self.positions.ndim != 3 or self.positions.shape[2] != 3:
            raise MocapFormatError(f"positions must have shape (n_frames, n_markers, 3), got {self.positions.shape}")
        n_frames, n_markers, _ = self.positions.shape
        if n_markers != len(self.marker_names):
            raise MocapFormatError(
                f"{len(self.marker_names)} marker names but positions hold {n_markers} markers"
            )
        if len(set(self.marker_names)) != len(self.marker_names):
            dup = sorted({n for n in self.marker_names if self.marker_names.count(n) > 1})
            raise MocapFormatError(f"duplicate marker names: {dup}")
        if np.isinf(self.positions).any():
            raise MocapFormatError("positions contain infinite values")
        self.frequency = float(self.frequency)
        if not np.isfinite(self.frequency) or self.frequency <= 0:
            raise MocapFormatError(f"frequency must be a positive number of Hz, got {self.frequency}")
        if self.frames is None:
            self.frames = np.arange(1, n_frames + 1, dtype=int)
        self.frames = np.asarray(self.frames, dtype=int)
        if self.time is None:
            self.time = (self.frames - 1) / self.frequency
        self.time = np.asarray(self.time, dtype=float)
        if self.frames.shape != (n_frames,) or self.time.shape != (n_frames,):
            raise MocapFormatError(
                f"frames {self.frames.shape} and time {self.time.shape} must both have shape ({n_frames},)"
            )
        if n_frames > 1 and np.any(np.diff(self.frames) <= 0):
            raise MocapFormatError("frame numbers must be strictly increasing")
        if not np.all(np.isfinite(self.time)):
            raise MocapFormatError("time values must be finite numbers")
        if n_frames > 1 and np.any(np.diff(self.time) <= 0):
            k = int(np.nonzero(np.diff(self.time) <= 0)[0][0])
            raise MocapFormatError(
                f"time must increase: frame {int(self.frames[k + 1])} has time {self.time[k + 1]:g} s "
                f"after {self.time[k]:g} s at frame {int(self.frames[k])}"
            )

    # ------------------------------------------------------------------ access
    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_markers(self) -> int:
        return int(self.positions.shape[1])

    @property
    def duration(self) -> float:
        """Seconds from the first to the last sample."""
        return float(self.time[-1] - self.time[0]) if self.n_frames else 0.0

    def marker_index(self, name: str) -> int:
        try:
            return self.marker_names.index(name)
        except ValueError:
            raise KeyError(f"no marker named {name!r}; available markers: {self.marker_names}") from None

    def marker(self, name: str) -> np.ndarray:
        """``(n_frames, 3)`` positions of one marker in metres (NaN where missing)."""
        return self.positions[:, self.marker_index(name), :]

    def frame_index(self, frame_number: int) -> int:
        """Row index of the sample with the file's frame number ``frame_number``."""
        i = int(np.searchsorted(self.frames, int(frame_number)))
        if i >= self.n_frames or self.frames[i] != int(frame_number):
            span = f"{self.frames[0]}..{self.frames[-1]}" if self.n_frames else "none"
            raise IndexError(f"frame {frame_number} is not in this recording (frames {span})")
        return i

    def visible(self) -> np.ndarray:
        """``(n_frames, n_markers)`` bool, True where a marker was seen."""
        return ~np.isnan(self.positions).any(axis=2)

    def copy(self) -> "MocapRecording":
        return MocapRecording(
            list(self.marker_names),
            self.positions.copy(),
            self.frequency,
            self.frames.copy(),
            self.time.copy(),
            copy.deepcopy(self.metadata),
        )

    def select(self, names: list[str]) -> "MocapRecording":
        """A recording with only the named markers, in the given order."""
        idx = [self.marker_index(n) for n in names]
        rec = self.copy()
        rec.marker_names = list(names)
        rec.positions = self.positions[:, idx, :].copy()
        return rec

    def crop(self, first_frame: int, last_frame: int) -> "MocapRecording":
        """The samples whose frame numbers lie in ``[first_frame, last_frame]``, numbering kept."""
        keep = (self.frames >= first_frame) & (self.frames <= last_frame)
        rec = self.copy()
        rec.positions, rec.frames, rec.time = rec.positions[keep], rec.frames[keep], rec.time[keep]
        return rec

    # ------------------------------------------------------------------ checks
    def spatial_extent(self) -> float:
        """Largest bounding-box side (metres) over all visible samples; 0 if none is visible."""
        pts = self.positions.reshape(-1, 3)
        pts = pts[~np.isnan(pts).any(axis=1)]
        if len(pts) == 0:
            return 0.0
        return float(np.max(pts.max(axis=0) - pts.min(axis=0)))

    def units_problem(self) -> str | None:
        """A message if the extent does not fit a human in metres (wrong units), else None.

        A human recording spans between :data:`MIN_PLAUSIBLE_EXTENT_M` (2 cm) and
        :data:`MAX_PLAUSIBLE_EXTENT_M` (50 m) once converted to metres. Recordings with fewer
        than two visible markers or frames are not judged.
        """
        vis = self.visible()
        if vis.sum() < 2:
            return None
        extent = self.spatial_extent()
        if extent > MAX_PLAUSIBLE_EXTENT_M:
            return (
                f"markers span {extent:.3g} m, more than {MAX_PLAUSIBLE_EXTENT_M:g} m: "
                "the file's units are probably not millimetres (micrometres?)"
            )
        if extent < MIN_PLAUSIBLE_EXTENT_M and vis.any(axis=0).sum() >= 2:
            return (
                f"markers span only {extent * 1000:.3g} mm: the file's values are probably "
                "already in metres (or centimetres), not millimetres"
            )
        return None

    def plate_edge(self) -> float | None:
        """Median edge length (metres) of the named rigid plates (:data:`PLATES`) present, None if none is."""
        edges = []
        for plate in PLATES:
            if all(n in self.marker_names for n in plate):
                for a, b in ((0, 1), (0, 2), (1, 2)):
                    d = np.linalg.norm(self.marker(plate[a]) - self.marker(plate[b]), axis=1)
                    edges.extend(d[np.isfinite(d)])
        return float(np.median(edges)) if edges else None

    def plate_units_problem(self) -> str | None:
        """A message naming the file's likely unit when the plates' edges lie outside :data:`PLATE_EDGE_RANGE_M`
        (their known size) by a unit's factor (10, 1000, 1/1000), else None."""
        edge = self.plate_edge()
        lo, hi = PLATE_EDGE_RANGE_M
        if edge is None or edge <= 0 or lo <= edge <= hi:
            return None
        for unit, factor in (("centimetres", 10.0), ("metres", 1000.0), ("micrometres", 1e-3)):
            if lo <= edge * factor <= hi:
                return (f"the rigid plates' markers are {edge * 1000:.3g} mm apart where the plates measure "
                        f"{lo * 1000:g}-{hi * 1000:g} mm: the file is probably in {unit}, not millimetres")
        return None  # no unit explains it: other plates (or made-up markers), not a unit mistake

    def check_units(self, source: str | Path, strict: bool = True) -> "MocapRecording":
        """Apply :meth:`units_problem` after reading ``source``: raise :class:`MocapUnitsError`
        naming the file (``strict``) or record the problem as ``metadata["units_warning"]``."""
        problem = self.units_problem() or self.plate_units_problem()
        if problem is not None:
            if strict:
                raise MocapUnitsError(f"{source}: {problem}")
            self.metadata["units_warning"] = problem
        return self

    def missing_markers(self) -> list[str]:
        """Names of markers that are never visible."""
        vis = self.visible().any(axis=0)
        return [n for n, v in zip(self.marker_names, vis) if not v]
