"""Imitation of real human movements (pick-and-place motion capture, ../shared/data) with the
Cartesian DMP, as in the paper's pick-and-place scenario (hand position and orientation)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from besdrake.imitation import CartesianDMP
from besdrake.imitation import quaternion as quat

RUNS = ("subject1_run1", "subject2_run1")


def _hand_segments(folder: Path, run: str) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(label, times (N,) s, hand poses (N, 7)) of every complete, gap-free labelled movement."""
    from besdrake.mocap.qualisys import read_tsv

    recording = read_tsv(folder / f"{run}.tsv")
    segments = json.loads((folder / f"{run}_manually_segmented.json").read_text())
    names = recording.marker_names
    out = []
    for seg in segments:
        if seg["label"] == "idle" or seg["label"].endswith("_part"):
            continue
        i0 = int(np.searchsorted(recording.frames, seg["start index"]))
        i1 = int(np.searchsorted(recording.frames, seg["end index"]))
        markers = recording.positions[i0 : i1 + 1]
        top, right, left = (markers[:, names.index(n)] for n in ("Hand top", "Hand right", "Hand left"))
        if np.isnan(top).any() or np.isnan(right).any() or np.isnan(left).any():
            continue
        x = right - left
        x /= np.linalg.norm(x, axis=1, keepdims=True)
        z = top - 0.5 * (right + left)
        z -= np.sum(z * x, axis=1, keepdims=True) * x
        z /= np.linalg.norm(z, axis=1, keepdims=True)
        rotation = np.stack((x, np.cross(z, x), z), axis=2)
        q = Rotation.from_matrix(rotation).as_quat(scalar_first=True)
        out.append((seg["label"], recording.time[i0 : i1 + 1], np.hstack((top, q))))
    return out


@pytest.mark.parametrize("run", RUNS)
def test_cartesian_dmp_reproduces_real_hand_movements(shared_data: Path, run: str) -> None:
    segments = _hand_segments(shared_data / "pick_and_place", run)
    assert len(segments) >= 4, "expected several gap-free labelled movements"
    for label, t, poses in segments:
        dmp = CartesianDMP(10).fit(t, poses)
        assert dmp.execution_time == pytest.approx(t[-1] - t[0])
        traj = dmp.open_loop(dt=1.0 / 60.0)
        # Compare at the demonstration's own times (relative to its start).
        position = np.column_stack([np.interp(t - t[0], traj.t, traj.pose[:, i]) for i in range(3)])
        error = np.linalg.norm(position - poses[:, :3], axis=1)
        assert np.sqrt(np.mean(error**2)) < 0.01, label  # m
        assert error.max() < 0.02, label
        assert np.linalg.norm(traj.pose[-1, :3] - poses[-1, :3]) < 0.01, label
        demo_q = quat.make_continuous(poses[:, 3:])
        n = min(traj.t.size, t.size)
        angle = 2 * np.arccos(np.clip(np.abs(np.sum(traj.pose[:n, 3:] * demo_q[:n], axis=1)), 0.0, 1.0))
        assert angle.max() < 0.15, label  # rad
        final = 2 * np.arccos(min(1.0, abs(float(np.dot(traj.pose[-1, 3:], demo_q[-1])))))
        assert final < 0.03, label
