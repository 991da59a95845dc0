"""The state of one labeling (:meth:`besdrake.mocap.labeling.MarkerLabeler.predict`): each tracklet's frames and points,
the label each holds, and per (frame, label) the position, whether it is taken and by which tracklet."""

from __future__ import annotations

import numpy as np

#: Label of a tracklet that holds none (a ghost).
GHOST = -1


class LabelAssignment:
    """Tracklets of a recording and the labels they hold; :meth:`assign` and :meth:`unassign` keep the per-frame
    tables consistent (a tracklet that takes a label displaces the tracklets holding it in its frames)."""

    def __init__(self, pos: np.ndarray, tid: np.ndarray, n_tracklets: int, n_labels: int) -> None:
        n = pos.shape[0]
        self.n_tracklets = n_tracklets
        self.rows_of, self.pts_of = _tracklet_points(pos, tid, n_tracklets)
        self.label_pos = np.full((n, n_labels, 3), np.nan)
        self.occupied = np.zeros((n, n_labels), dtype=bool)
        self.owner = np.full((n, n_labels), -1, dtype=int)
        self.label_of = np.full(n_tracklets, GHOST, dtype=int)
        self.lengths = np.array([len(r) for r in self.rows_of])

    def assign(self, t: int, lab: int) -> None:
        """Tracklet ``t`` takes label ``lab`` (displacing whatever held it in ``t``'s frames)."""
        for u in np.unique(self.owner[self.rows_of[t], lab]):
            if u >= 0:  # displaced (only ever a much shorter trajectory)
                self.unassign(int(u))
        self.label_of[t] = lab
        self.label_pos[self.rows_of[t], lab] = self.pts_of[t]
        self.occupied[self.rows_of[t], lab] = True
        self.owner[self.rows_of[t], lab] = t

    def unassign(self, t: int) -> None:
        """Tracklet ``t`` gives its label up (becomes a ghost)."""
        lab = self.label_of[t]
        if lab >= 0:
            self.label_pos[self.rows_of[t], lab] = np.nan
            self.occupied[self.rows_of[t], lab] = False
            self.owner[self.rows_of[t], lab] = -1
            self.label_of[t] = GHOST


def _tracklet_points(pos: np.ndarray, tid: np.ndarray, n_t: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per tracklet its frame rows and positions, from the tracklet id of each (frame, slot)."""
    rows_of: list[np.ndarray] = [None] * n_t  # type: ignore[list-item]
    pts_of: list[np.ndarray] = [None] * n_t  # type: ignore[list-item]
    f_idx, s_idx = np.nonzero(tid >= 0)
    order = np.argsort(tid[f_idx, s_idx], kind="stable")
    f_idx, s_idx = f_idx[order], s_idx[order]
    bounds = np.searchsorted(tid[f_idx, s_idx], np.arange(n_t + 1))
    for t in range(n_t):
        fr, sl = f_idx[bounds[t] : bounds[t + 1]], s_idx[bounds[t] : bounds[t + 1]]
        rows_of[t], pts_of[t] = fr, pos[fr, sl]
    return rows_of, pts_of
