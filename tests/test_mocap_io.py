"""Qualisys TSV / C3D reading and writing, and segmentation files."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from besdrake.mocap.qualisys import (
    MocapFormatError,
    MocapRecording,
    MocapUnitsError,
    Segment,
    read_recording,
    read_segmentation,
    read_tsv,
    segmentation_path,
    write_recording,
    write_segmentation,
    write_tsv,
)

HEADER = (
    "NO_OF_FRAMES\t{nf}\nNO_OF_CAMERAS\t7\nNO_OF_MARKERS\t{nm}\nFREQUENCY\t100\nNO_OF_ANALOG\t0\n"
    "ANALOG_FREQUENCY\t0\nDESCRIPTION\t--\nTIME_STAMP\t2015-11-12, 11:51:16\t6281.3\nDATA_INCLUDED\t3D\n"
)


def _small_tsv(tmp_path: Path, rows: list[str], names=("A", "B"), nf=10, nm=None, extra="", column_line=True) -> Path:
    text = HEADER.format(nf=nf, nm=len(names) if nm is None else nm) + extra
    text += "MARKER_NAMES\t" + "\t".join(names) + "\n"
    if column_line:
        text += "Frame\tTime\t" + "\t".join(f"{n} {a}" for n in names for a in "XYZ") + "\t\n"
    text += "\n".join(rows) + "\n"
    p = tmp_path / "small.tsv"
    p.write_text(text)
    return p


GOOD_ROWS = [
    "5\t0.04000\t100.0\t200.0\t300.0\t400.0\t500.0\t600.0\t",
    "6\t0.05000\tnull\tnull\tnull\t401.0\t501.0\t601.0\t",
    "7\t0.06000\t0.000\t0.000\t0.000\t402.0\t502.0\t602.0",
]


def test_small_file_units_missing_and_cropped_numbering(tmp_path):
    rec = read_tsv(_small_tsv(tmp_path, GOOD_ROWS))
    assert rec.marker_names == ["A", "B"]
    assert rec.positions.shape == (3, 2, 3)
    np.testing.assert_allclose(rec.marker("A")[0], [0.1, 0.2, 0.3])
    assert np.isnan(rec.marker("A")[1]).all() and np.isnan(rec.marker("A")[2]).all()  # null and all-zero
    np.testing.assert_allclose(rec.marker("B")[2], [0.402, 0.502, 0.602])
    assert rec.frames.tolist() == [5, 6, 7]
    assert rec.frame_index(6) == 1
    np.testing.assert_allclose(rec.time, [0.04, 0.05, 0.06])
    assert rec.frequency == 100.0
    with pytest.raises(KeyError, match="available markers"):
        rec.marker("Nose")
    with pytest.raises(IndexError, match="frames 5..7"):
        rec.frame_index(1)


def test_without_frame_time_columns_and_with_optional_headers(tmp_path):
    rows = ["100.0\t200.0\t300.0\t400.0\t500.0\t600.0", "101.0\t201.0\t301.0\t401.0\t501.0\t601.0"]
    extra = "FILE_VERSION\t2\nEVENT\tstart\t1\t0.0\nEVENT\tstop\t2\t0.01\n"
    p = _small_tsv(tmp_path, rows, extra=extra, column_line=False)
    p.write_text(p.read_text().replace("MARKER_NAMES\tA\tB\n", "MARKER_NAMES\tA\tB\nTRAJECTORY_TYPES\tMeasured\tMeasured\n"))
    rec = read_tsv(p)
    assert rec.frames.tolist() == [1, 2]
    np.testing.assert_allclose(rec.time, [0.0, 0.01])
    assert rec.metadata["FILE_VERSION"] == "2"
    assert rec.metadata["EVENT"] == [["start", "1", "0.0"], ["stop", "2", "0.01"]]
    out = tmp_path / "out.tsv"
    write_tsv(rec, out)
    back = read_tsv(out)
    assert back.metadata["EVENT"] == rec.metadata["EVENT"]
    assert back.metadata["TRAJECTORY_TYPES"] == ["Measured", "Measured"]
    np.testing.assert_allclose(back.positions, rec.positions)


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda rows: rows[:-1] + ["7\t0.06000\t1.0\t2.0"], r"line 14: 4 columns.*truncated"),
        (lambda rows: [rows[0], rows[1].replace("401.0", "4x1.0"), rows[2]], r"line 13: column 6 is not a number: '4x1.0'"),
        (lambda rows: [rows[0], rows[0], rows[2]], r"line 13: Frame numbers must increase"),
    ],
)
def test_malformed_rows_name_the_line(tmp_path, mutate, message):
    with pytest.raises(MocapFormatError, match=message):
        read_tsv(_small_tsv(tmp_path, mutate(list(GOOD_ROWS))))


def test_header_problems(tmp_path):
    with pytest.raises(MocapFormatError, match="NO_OF_MARKERS says 3 but MARKER_NAMES lists 2"):
        read_tsv(_small_tsv(tmp_path, GOOD_ROWS, nm=3))
    p = _small_tsv(tmp_path, GOOD_ROWS)
    p.write_text(p.read_text().replace("MARKER_NAMES\tA\tB\n", ""))
    with pytest.raises(MocapFormatError, match="no MARKER_NAMES"):
        read_tsv(p)
    p = _small_tsv(tmp_path, [])
    with pytest.raises(MocapFormatError, match="no data rows"):
        read_tsv(p)
    with pytest.raises(MocapFormatError, match="NO_OF_FRAMES says 2 but the file has 3"):
        read_tsv(_small_tsv(tmp_path, GOOD_ROWS, nf=2))


def test_wrong_units_are_caught(tmp_path):
    # Values written in metres but read as millimetres: everything within 1 mm.
    rows_m = ["5\t0.04\t0.100\t0.200\t0.300\t0.400\t0.500\t0.600", "6\t0.05\t0.101\t0.201\t0.301\t0.401\t0.501\t0.601"]
    with pytest.raises(MocapUnitsError, match="already in metres"):
        read_tsv(_small_tsv(tmp_path, rows_m))
    rec = read_tsv(_small_tsv(tmp_path, rows_m), check_units=False)
    assert "metres" in rec.metadata["units_warning"]
    # Micrometres read as millimetres: a human spanning hundreds of metres.
    rows_um = ["5\t0.04\t100000\t200000\t300000\t900000\t500000\t600000"]
    with pytest.raises(MocapUnitsError, match="micrometres"):
        read_tsv(_small_tsv(tmp_path, rows_um))


def test_never_visible_marker_is_reported(tmp_path):
    rows = [f"{k}\t{k / 100:.5f}\tnull\tnull\tnull\t{400 + k}.0\t500.0\t600.0" for k in range(1, 4)]
    rows[0] = rows[0].replace("\t400", "\t200")
    rec = read_tsv(_small_tsv(tmp_path, rows))
    assert rec.missing_markers() == ["A"]


def test_recording_validation():
    with pytest.raises(MocapFormatError, match="2 marker names"):
        MocapRecording(["a", "b"], np.zeros((4, 3, 3)), 100.0)
    with pytest.raises(MocapFormatError, match="frequency"):
        MocapRecording(["a"], np.zeros((4, 1, 3)), 0.0)
    with pytest.raises(MocapFormatError, match="duplicate"):
        MocapRecording(["a", "a"], np.zeros((4, 2, 3)), 10.0)


def test_real_pick_and_place_files_load(shared_data):
    files = sorted((shared_data / "pick_and_place").glob("*.tsv"))
    assert len(files) >= 10
    for f in files:
        rec = read_tsv(f)
        assert rec.frequency == 60.0
        assert rec.n_markers == 13 and "Back top" in rec.marker_names
        assert rec.frames[0] > 1 and int(rec.metadata["NO_OF_FRAMES"]) > rec.n_frames
        np.testing.assert_array_equal(np.diff(rec.frames), 1)
        np.testing.assert_allclose(rec.time, (rec.frames - 1) / 60.0, atol=1e-5)
        assert 0.3 < rec.spatial_extent() < 5.0  # metres
        segs = read_segmentation(segmentation_path(f))
        assert segs and all(rec.frames[0] <= s.start_frame <= s.end_frame <= rec.frames[-1] for s in segs)
        assert rec.frame_index(segs[0].start_frame) == segs[0].start_frame - rec.frames[0]


def test_real_file_tsv_and_c3d_round_trip(shared_data, tmp_path):
    rec = read_tsv(shared_data / "pick_and_place" / "subject1_run1.tsv")
    rec.positions[10:20, 3] = np.nan  # a gap
    for ext, tol in ((".tsv", 5e-7), (".c3d", 1e-6)):
        out = tmp_path / f"copy{ext}"
        write_recording(rec, out)
        back = read_recording(out)
        assert back.marker_names == rec.marker_names
        np.testing.assert_array_equal(back.frames, rec.frames)
        np.testing.assert_array_equal(np.isnan(back.positions), np.isnan(rec.positions))
        np.testing.assert_allclose(back.positions, rec.positions, atol=tol, equal_nan=True)
        np.testing.assert_allclose(back.time, rec.time, atol=1e-5)
        assert back.frequency == rec.frequency


def test_zero_missing_style_and_unknown_extension(tmp_path):
    rec = MocapRecording(["A", "B"], np.array([[[0.1, 0.2, 0.3], [np.nan] * 3], [[0.1, 0.2, 0.31], [1.0, 1.0, 1.0]]]), 120.0)
    out = tmp_path / "z.tsv"
    write_tsv(rec, out, missing="zero", frame_time=False)
    assert "null" not in out.read_text()
    back = read_tsv(out)
    np.testing.assert_array_equal(np.isnan(back.positions), np.isnan(rec.positions))
    with pytest.raises(MocapFormatError, match="unknown recording format"):
        read_recording(tmp_path / "x.csv")
    bad = tmp_path / "bad.c3d"
    bad.write_bytes(b"\x00\x01garbage" * 10)
    with pytest.raises(MocapFormatError, match="C3D"):
        read_recording(bad)


def test_segmentation_round_trip_and_errors(tmp_path):
    segs = [Segment(10, 40, "strike_out"), Segment(40, 70, "throw")]
    p = tmp_path / "a_manually_segmented.json"
    write_segmentation(segs, p)
    assert json.loads(p.read_text())[0] == {"start index": 10, "end index": 40, "label": "strike_out"}
    assert read_segmentation(p) == segs
    assert segmentation_path(tmp_path / "a.tsv") == p
    p.write_text('[{"start index": 5, "label": "x"}]')
    with pytest.raises(MocapFormatError, match="segment 0 needs"):
        read_segmentation(p)
    p.write_text('[{"start index": 5, "end index": 2, "label": "x"}]')
    with pytest.raises(MocapFormatError, match="ends"):
        read_segmentation(p)
    p.write_text("[{")
    with pytest.raises(MocapFormatError, match="not valid JSON"):
        read_segmentation(p)


def test_c3d_in_metres_and_binary_tsv(tmp_path):
    import c3d

    writer = c3d.Writer(point_rate=50.0, point_units="m   ")
    writer.set_point_labels(["A", "B"])
    pts = np.zeros((2, 5), dtype=np.float32)
    pts[0, :3] = [0.1, 0.2, 1.3]
    pts[1, :3] = [0.5, 0.2, 1.0]
    missing = pts.copy()
    missing[1, 3] = -1.0
    writer.add_frames([(pts, np.zeros((0, 0), dtype=np.float32)), (missing, np.zeros((0, 0), dtype=np.float32))])
    path = tmp_path / "m.c3d"
    with open(path, "wb") as handle, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the c3d package warns about the absent analog data
        writer.write(handle)
    rec = read_recording(path)
    np.testing.assert_allclose(rec.marker("A")[0], [0.1, 0.2, 1.3], atol=1e-6)
    assert np.isnan(rec.marker("B")[1]).all() and rec.frequency == 50.0
    binary = tmp_path / "not_text.tsv"
    binary.write_bytes(bytes(range(256)))
    with pytest.raises(MocapFormatError, match="not a text file"):
        read_tsv(binary)
