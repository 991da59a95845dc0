"""Qualisys TSV exports: read and write (millimetres in the file, metres in memory).

A file is a block of header lines ``KEY<TAB>value...`` (NO_OF_FRAMES, NO_OF_CAMERAS,
NO_OF_MARKERS, FREQUENCY, NO_OF_ANALOG, ANALOG_FREQUENCY, DESCRIPTION, TIME_STAMP,
DATA_INCLUDED, optional FILE_VERSION, EVENT and TRAJECTORY_TYPES, then MARKER_NAMES), an
optional column line (``Frame<TAB>Time<TAB>Name X...``) and data rows, with or without the
Frame and Time columns. A missing sample is ``null`` or an all-zero triplet. Lines may end in a
trailing tab. Cropped exports start at a Frame greater than 1 and keep the original
NO_OF_FRAMES.

The segmentation file beside a recording is handled by :mod:`besdrake.mocap.segments_io`
(re-exported here).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from besdrake._io import write_text as _atomic_write_text
from besdrake.mocap.recording import MocapFormatError, MocapRecording, MocapUnitsError
from besdrake.mocap.segments_io import Segment, read_segmentation, segmentation_path, write_segmentation

__all__ = [
    "MocapFormatError",
    "MocapRecording",
    "MocapUnitsError",
    "Segment",
    "read_recording",
    "read_segmentation",
    "read_tsv",
    "segmentation_path",
    "write_recording",
    "write_segmentation",
    "write_tsv",
]

MM_PER_M = 1000.0

#: Header keys in the order Qualisys writes them.
HEADER_KEYS = (
    "FILE_VERSION",
    "NO_OF_FRAMES",
    "NO_OF_CAMERAS",
    "NO_OF_MARKERS",
    "FREQUENCY",
    "NO_OF_ANALOG",
    "ANALOG_FREQUENCY",
    "DESCRIPTION",
    "TIME_STAMP",
    "DATA_INCLUDED",
)
_MULTI_KEYS = ("EVENT",)  # may occur several times: stored as a list of value lists


def _is_header_line(fields: list[str]) -> bool:
    key = fields[0]
    return bool(key) and key.replace("_", "").isalpha() and key.isupper()


def _parse_floats(rows: list[list[str]], first_line: int, path: Path) -> np.ndarray:
    """Rows of strings -> float array; ``null``/empty become NaN; errors name the line."""
    try:
        arr = np.array(rows, dtype=object)
        arr[(arr == "null") | (arr == "") | (arr == "NaN")] = "nan"
        return arr.astype(float)
    except ValueError:
        pass
    for k, row in enumerate(rows):
        for col, value in enumerate(row):
            if value in ("null", "", "NaN"):
                continue
            try:
                float(value)
            except ValueError:
                raise MocapFormatError(
                    f"{path}, line {first_line + k}: column {col + 1} is not a number: {value!r}"
                ) from None
    raise MocapFormatError(f"{path}: data rows could not be read as numbers")  # pragma: no cover


def _decimals(value: str) -> int | None:
    """Digits after the decimal point of a number field (None for a missing sample)."""
    if value in ("null", "", "NaN"):
        return None
    return len(value.partition(".")[2])


def _check_last_row(rows: list[list[str]], line: int, path: Path) -> None:
    """A file that ends without a newline may have been cut off inside its last number: refuse a last row
    whose fields carry fewer decimals than the same fields of the row before it."""
    if len(rows) < 2:
        return
    for col, (a, b) in enumerate(zip(rows[-2], rows[-1])):
        da, db = _decimals(a), _decimals(b)
        if da is not None and db is not None and db < da:
            raise MocapFormatError(
                f"{path}, line {line}: the file ends without a newline and column {col + 1} ({b!r}) has fewer "
                f"digits than the line before ({a!r}): the file seems truncated; remove or complete the last line"
            )


def read_tsv(path: str | Path, check_units: bool = True) -> MocapRecording:
    """Read a Qualisys TSV export (3D marker data) into a :class:`MocapRecording` in metres.

    Raises :class:`MocapFormatError` naming the file and line for a malformed or truncated file,
    and :class:`MocapUnitsError` when the marker positions span more than 50 m or less than
    2 cm after conversion (``check_units=False`` skips that check and instead records the
    problem in ``metadata["units_warning"]``).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise MocapFormatError(f"{path}: not a text file (is it a C3D file?)") from None
    lines = text.splitlines()
    metadata, marker_names, i = _read_header(lines, path)
    n_markers = len(marker_names)
    frequency = _header_frequency(metadata, n_markers, path)
    has_frame_time, i = _read_column_line(lines, i, n_markers, path)
    first_data_line = i + 1
    rows, line_numbers = _data_rows(lines, i, path)
    if has_frame_time is None:
        has_frame_time = _layout_from_row(rows[0], line_numbers[0], n_markers, path)
    _check_row_lengths(rows, line_numbers, 3 * n_markers + (2 if has_frame_time else 0), n_markers, path)
    if not text.endswith(("\n", "\r")):
        _check_last_row(rows, line_numbers[-1], path)
    data = _parse_floats(rows, first_data_line, path)
    if has_frame_time:
        frames, time, coords = _frames_and_time(data, line_numbers, path)
    else:
        frames = np.arange(1, len(rows) + 1)
        time = (frames - 1) / frequency
        coords = data
    positions = coords.reshape(len(rows), n_markers, 3) / MM_PER_M
    positions[np.all(positions == 0.0, axis=2)] = np.nan
    _check_declared_frames(metadata, len(rows), path)
    metadata["HAS_FRAME_TIME"] = bool(has_frame_time)
    return MocapRecording(marker_names, positions, frequency, frames, time, metadata).check_units(path, strict=check_units)


def _read_header(lines: list[str], path: Path) -> tuple[dict, list[str], int]:
    """The header lines (up to the first non-header line): metadata, the marker names, the index of the next line."""
    metadata: dict = {}
    marker_names: list[str] | None = None
    trajectory_types: list[str] | None = None
    i = 0
    while i < len(lines):
        raw = lines[i].rstrip("\r\n")
        fields = raw.rstrip("\t").split("\t")
        if not raw.strip():
            i += 1
            continue
        if not _is_header_line(fields):
            break
        key, values = fields[0], fields[1:]
        if key == "MARKER_NAMES":
            marker_names = [v.strip() for v in values]
        elif key == "TRAJECTORY_TYPES":
            trajectory_types = values
        elif key in _MULTI_KEYS:
            metadata.setdefault(key, []).append(values)
        else:
            metadata[key] = "\t".join(values)
        i += 1
    if marker_names is None:
        raise MocapFormatError(f"{path}: no MARKER_NAMES header line (is this a Qualisys TSV 3D export?)")
    if not marker_names or any(not n for n in marker_names):
        raise MocapFormatError(f"{path}: MARKER_NAMES line has empty names: {marker_names}")
    if trajectory_types is not None:
        metadata["TRAJECTORY_TYPES"] = trajectory_types
    return metadata, marker_names, i


def _header_frequency(metadata: dict, n_markers: int, path: Path) -> float:
    """The frame rate (Hz), after checking NO_OF_MARKERS against the marker names."""
    if "NO_OF_MARKERS" in metadata:
        try:
            declared = int(metadata["NO_OF_MARKERS"])
        except ValueError:
            raise MocapFormatError(f"{path}: NO_OF_MARKERS is not an integer: {metadata['NO_OF_MARKERS']!r}") from None
        if declared != n_markers:
            raise MocapFormatError(
                f"{path}: NO_OF_MARKERS says {declared} but MARKER_NAMES lists {n_markers} names"
            )
    if "FREQUENCY" not in metadata:
        raise MocapFormatError(f"{path}: no FREQUENCY header line")
    try:
        frequency = float(metadata["FREQUENCY"])
    except ValueError:
        raise MocapFormatError(f"{path}: FREQUENCY is not a number: {metadata['FREQUENCY']!r}") from None
    if not np.isfinite(frequency) or frequency <= 0:
        raise MocapFormatError(f"{path}: FREQUENCY must be positive, got {metadata['FREQUENCY']!r}")
    return frequency


def _read_column_line(lines: list[str], i: int, n_markers: int, path: Path) -> tuple[bool | None, int]:
    """The optional column line at ``i``: whether it declares Frame and Time columns (None: no column line), and the
    index of the first data line."""
    if i >= len(lines):
        return None, i
    fields = lines[i].rstrip("\r\n").rstrip("\t").split("\t")
    if not (fields and fields[0] in ("Frame", "Time") or (len(fields) > 0 and fields[0].endswith(" X"))):
        return None, i
    has_frame_time = fields[0] == "Frame"
    if has_frame_time and (len(fields) < 2 or fields[1] != "Time"):
        raise MocapFormatError(f"{path}, line {i + 1}: column line starts with Frame but not Frame, Time")
    expected_cols = 3 * n_markers + (2 if has_frame_time else (1 if fields[0] == "Time" else 0))
    if len(fields) != expected_cols:
        raise MocapFormatError(
            f"{path}, line {i + 1}: column line has {len(fields)} columns, expected {expected_cols} "
            f"for {n_markers} markers"
        )
    if fields[0] == "Time":
        raise MocapFormatError(f"{path}, line {i + 1}: a Time column without Frame is not supported")
    return has_frame_time, i + 1


def _data_rows(lines: list[str], i: int, path: Path) -> tuple[list[list[str]], list[int]]:
    """The non-blank lines from ``i`` on, split into fields, with their 1-based line numbers."""
    rows: list[list[str]] = []
    line_numbers: list[int] = []
    for k in range(i, len(lines)):
        raw = lines[k].rstrip("\r\n")
        if not raw.strip():
            continue
        rows.append(raw.rstrip("\t").split("\t"))
        line_numbers.append(k + 1)
    if not rows:
        raise MocapFormatError(f"{path}: no data rows after the header (truncated file?)")
    return rows, line_numbers


def _layout_from_row(row: list[str], line: int, n_markers: int, path: Path) -> bool:
    """Without a column line: whether the first data row holds Frame and Time columns, from its length."""
    n0 = len(row)
    if n0 == 3 * n_markers + 2:
        return True
    if n0 == 3 * n_markers:
        return False
    raise MocapFormatError(
        f"{path}, line {line}: {n0} columns, expected {3 * n_markers} or "
        f"{3 * n_markers + 2} (with Frame and Time) for {n_markers} markers"
    )


def _check_row_lengths(rows: list[list[str]], line_numbers: list[int], n_cols: int, n_markers: int, path: Path) -> None:
    for row, ln in zip(rows, line_numbers):
        if len(row) != n_cols:
            raise MocapFormatError(
                f"{path}, line {ln}: {len(row)} columns, expected {n_cols} for {n_markers} markers"
                + (" (truncated file?)" if ln == line_numbers[-1] else "")
            )


def _frames_and_time(data: np.ndarray, line_numbers: list[int], path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frame numbers, times and marker coordinates of rows that start with Frame and Time (both must increase)."""
    if np.isnan(data[:, :2]).any():
        bad = line_numbers[int(np.nonzero(np.isnan(data[:, :2]).any(axis=1))[0][0])]
        raise MocapFormatError(f"{path}, line {bad}: Frame or Time is missing")
    frames_f = data[:, 0]
    if np.any(frames_f != np.round(frames_f)):
        bad = line_numbers[int(np.nonzero(frames_f != np.round(frames_f))[0][0])]
        raise MocapFormatError(f"{path}, line {bad}: Frame is not an integer")
    frames = frames_f.astype(int)
    time = data[:, 1]
    if len(frames) > 1 and np.any(np.diff(frames) <= 0):
        bad = line_numbers[int(np.nonzero(np.diff(frames) <= 0)[0][0]) + 1]
        raise MocapFormatError(f"{path}, line {bad}: Frame numbers must increase")
    if len(time) > 1 and np.any(np.diff(time) <= 0):
        bad = line_numbers[int(np.nonzero(np.diff(time) <= 0)[0][0]) + 1]
        raise MocapFormatError(f"{path}, line {bad}: Time must increase")
    return frames, time, data[:, 2:]


def _check_declared_frames(metadata: dict, n_rows: int, path: Path) -> None:
    """NO_OF_FRAMES, where given, must be an integer and not below the rows read (fewer rows is a truncated file)."""
    if "NO_OF_FRAMES" not in metadata:
        return
    try:
        declared_frames = int(metadata["NO_OF_FRAMES"])
    except ValueError:
        raise MocapFormatError(f"{path}: NO_OF_FRAMES is not an integer: {metadata['NO_OF_FRAMES']!r}") from None
    if declared_frames < n_rows:
        raise MocapFormatError(
            f"{path}: NO_OF_FRAMES says {declared_frames} but the file has {n_rows} data rows"
        )


def _fmt_header_value(value) -> str:
    if isinstance(value, (list, tuple)):
        return "\t".join(str(v) for v in value)
    return str(value)


def write_tsv(rec: MocapRecording, path: str | Path, missing: str = "null", frame_time: bool = True) -> None:
    """Write ``rec`` as a Qualisys TSV export in millimetres.

    ``missing`` is ``"null"`` (as newer exports) or ``"zero"`` (an all-zero triplet, as older
    ones); ``frame_time=False`` leaves out the Frame and Time columns.
    """
    if missing not in ("null", "zero"):
        raise ValueError(f"missing must be 'null' or 'zero', got {missing!r}")
    md = rec.metadata
    n_frames = rec.n_frames
    declared = md.get("NO_OF_FRAMES")
    try:
        declared_i = int(declared) if declared is not None else None
    except ValueError:
        declared_i = None
    last = int(rec.frames[-1]) if n_frames else 0
    no_of_frames = declared_i if declared_i is not None and declared_i >= max(last, n_frames) else max(last, n_frames)
    header = {
        "NO_OF_FRAMES": no_of_frames,
        "NO_OF_CAMERAS": md.get("NO_OF_CAMERAS", 0),
        "NO_OF_MARKERS": rec.n_markers,
        "FREQUENCY": _fmt_number(rec.frequency),
        "NO_OF_ANALOG": md.get("NO_OF_ANALOG", 0),
        "ANALOG_FREQUENCY": md.get("ANALOG_FREQUENCY", 0),
        "DESCRIPTION": md.get("DESCRIPTION", "--"),
        "TIME_STAMP": md.get("TIME_STAMP", "--"),
        "DATA_INCLUDED": md.get("DATA_INCLUDED", "3D"),
    }
    out: list[str] = []
    if "FILE_VERSION" in md:
        out.append(f"FILE_VERSION\t{_fmt_header_value(md['FILE_VERSION'])}")
    for key, value in header.items():
        out.append(f"{key}\t{_fmt_header_value(value)}")
    for values in md.get("EVENT", []):
        out.append("EVENT\t" + _fmt_header_value(values))
    out.append("MARKER_NAMES\t" + "\t".join(rec.marker_names))
    types = md.get("TRAJECTORY_TYPES")
    if types is not None and len(types) == rec.n_markers:
        out.append("TRAJECTORY_TYPES\t" + "\t".join(types))
    cols = [f"{n} {a}" for n in rec.marker_names for a in "XYZ"]
    if frame_time:
        cols = ["Frame", "Time"] + cols
    out.append("\t".join(cols))
    mm = rec.positions.reshape(n_frames, -1) * MM_PER_M
    text = np.char.mod("%.3f", mm)
    nan = np.isnan(mm)
    text[nan] = "null" if missing == "null" else "0.000"
    for k in range(n_frames):
        row = "\t".join(text[k])
        if frame_time:
            row = f"{int(rec.frames[k])}\t{rec.time[k]:.5f}\t" + row
        out.append(row)
    _atomic_write_text(Path(path), "\n".join(out) + "\n")


def _fmt_number(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else repr(float(x))


def read_recording(path: str | Path, **kwargs) -> MocapRecording:
    """Read a ``.tsv`` (Qualisys) or ``.c3d`` recording, chosen by the file extension."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".tsv":
        return read_tsv(path, **kwargs)
    if suffix == ".c3d":
        from besdrake.mocap.c3d_io import read_c3d

        return read_c3d(path, **kwargs)
    raise MocapFormatError(f"{path}: unknown recording format {suffix!r} (expected .tsv or .c3d)")


def write_recording(rec: MocapRecording, path: str | Path) -> None:
    """Write a ``.tsv`` or ``.c3d`` recording, chosen by the file extension."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".tsv":
        write_tsv(rec, path)
    elif suffix == ".c3d":
        from besdrake.mocap.c3d_io import write_c3d

        write_c3d(rec, path)
    else:
        raise ValueError(f"{path}: unknown recording format {suffix!r} (expected .tsv or .c3d)")
