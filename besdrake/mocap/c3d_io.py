"""C3D files through the ``c3d`` package (points only; analog channels are ignored).

Points are read in the file's POINT:UNITS (``mm`` or ``m``) and converted to metres; a
missing sample is a point whose residual is negative (the C3D convention). Written files use
millimetres, float storage and the recording's first frame number.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from besdrake.mocap.recording import MocapFormatError, MocapRecording, MocapUnitsError

_UNIT_TO_M = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}


def read_c3d(path: str | Path, check_units: bool = True) -> MocapRecording:
    """Read the 3-D points of a C3D file into a :class:`MocapRecording` in metres."""
    import c3d

    path = Path(path)
    try:
        with open(path, "rb") as handle, warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="No analog data found")
            warnings.filterwarnings("ignore", message="reached end of file")  # checked below: frames read < declared
            warnings.filterwarnings("ignore", category=UserWarning, module="c3d")  # damaged files: an error below or a read
            reader = c3d.Reader(handle)
            labels = [str(s).strip() for s in reader.point_labels]
            rate = float(reader.point_rate)
            first = int(reader.first_frame)
            declared = int(reader.last_frame) - first + 1
            units_param = reader.get("POINT:UNITS")
            units = units_param.string_value.strip().lower() if units_param is not None else "mm"
            pts = []
            for _, points, _analog in reader.read_frames(copy=True, check_nan=False):
                pts.append(points[:, :4])
    except Exception as err:  # noqa: BLE001 - the c3d package raises anything on damaged bytes
        if isinstance(err, (FileNotFoundError, PermissionError, IsADirectoryError)):
            raise
        raise MocapFormatError(f"{path}: not a readable C3D file ({type(err).__name__}: {err})") from None
    if not pts:
        raise MocapFormatError(f"{path}: C3D file holds no frames")
    if len(pts) < declared:
        raise MocapFormatError(f"{path}: truncated C3D file: its header declares {declared} frames, the file holds {len(pts)}")
    if units not in _UNIT_TO_M:
        raise MocapUnitsError(f"{path}: unknown POINT:UNITS {units!r} (expected mm, cm or m)")
    data = np.stack(pts).astype(float)  # (n_frames, n_points, 4)
    positions = data[:, :, :3] * _UNIT_TO_M[units]
    positions[data[:, :, 3] < 0] = np.nan
    n_labels = data.shape[1]
    labels = labels[:n_labels] + [f"Marker {k + 1}" for k in range(len(labels), n_labels)]
    frames = first + np.arange(len(pts))
    rec = MocapRecording(labels, positions, rate, frames, (frames - 1) / rate, {"C3D_POINT_UNITS": units})
    return rec.check_units(path, strict=check_units)


def write_c3d(rec: MocapRecording, path: str | Path) -> None:
    """Write the recording's markers as C3D points (millimetres, float storage)."""
    import c3d

    writer = c3d.Writer(point_rate=float(rec.frequency), analog_rate=0.0, point_scale=-1.0, point_units="mm  ")
    writer.set_point_labels(rec.marker_names)
    writer.set_start_frame(int(rec.frames[0]) if rec.n_frames else 1)
    frames = []
    empty_analog = np.zeros((0, 0), dtype=np.float32)
    for k in range(rec.n_frames):
        pts = np.zeros((rec.n_markers, 5), dtype=np.float32)
        p = rec.positions[k] * 1000.0
        missing = np.isnan(p).any(axis=1)
        pts[:, :3] = np.where(missing[:, None], 0.0, p)
        pts[:, 3] = np.where(missing, -1.0, 0.0)
        frames.append((pts, empty_analog))
    writer.add_frames(frames)
    from besdrake._io import atomic_path

    with atomic_path(path) as tmp, open(tmp, "wb") as handle, warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="No analog data found")
        writer.write(handle)
