"""Automatic marker labelling from relative distances, learned from one labelled recording.

The paper's labeller needs "neighbouring markers, initial pose". Here :class:`MarkerLabeler`
learns from one labelled reference recording of the same marker set (same subject and marker
placement):

* for every pair of markers, the distribution of their distance: a smoothed histogram, and for
  rigid pairs (plates) a Gaussian, fine enough to tell nearly isosceles plates apart;
* the rigid plates: disjoint triples whose pairwise distances vary by less than ``rigid_tol``
  (the back and hand plates), most rigid first;
* how well each true marker fits its neighbours in the reference (per-label cost thresholds).

The cost of a point for a label is the mean, over the labelled markers visible at the same
time, of the pair costs (-log density), weighted towards sharp (rigid) neighbours.

:meth:`MarkerLabeler.predict` labels a recording of unnamed trajectories:

1. *Tracking*: points are linked frame to frame into tracklets (constant-velocity prediction,
   Hungarian assignment, a gate of a few times each tracklet's recent prediction error, so a
   neighbouring plate marker is not taken over when a marker vanishes). Slot numbers play no
   role, so identities shuffled per gap or per frame are the same problem.
2. *Seed*: at the frame where most long tracklets coexist, whole plates are assigned first (the
   triple that best fits the learned distances), the initial pose.
3. *Identification*, most certain first: repeatedly, the tracklet whose best label beats its
   runner-up by the widest margin takes it, if its cost passes the label's threshold or if it
   continues the label's motion across a gap (prediction from the neighbouring frames).
   Short tracklets (< ``min_length_s``) pass a stricter threshold, and a short piece of a single
   (non-plate) marker must continue that marker's motion: alone, such pieces are mostly ghosts.
   What fits nothing is a ghost.
4. *Refinement*: every tracklet is re-decided with all others labelled; a long one may take over
   a label held only by short pieces. Long tracklets that still fit nothing take the free label
   they fit best within ``elimination_factor`` times its threshold (reported in the warnings:
   e.g. a marker re-attached since the reference).
5. *Gap filling* (:mod:`besdrake.mocap.gaps`): rigid fits for plate markers, splines otherwise;
   long gaps are flagged.
"""

from __future__ import annotations

import itertools
import time as _time
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.optimize import linear_sum_assignment

from besdrake.mocap.gaps import GapFillResult, GapInfo, fill_gaps
from besdrake.mocap.label_state import GHOST, LabelAssignment
from besdrake.mocap.recording import MocapRecording

EMPTY = -2


class LabelingError(ValueError):
    """A reference or input recording that cannot be used for labelling."""


@dataclass
class LabelingResult:
    """Output of :meth:`MarkerLabeler.predict`.

    ``slot_labels`` is ``(n_frames, n_slots)``: the label index (into ``marker_names``) given to
    each input trajectory slot per frame, :data:`GHOST` (-1) for a rejected point and
    :data:`EMPTY` (-2) where the slot holds nothing. ``recording`` has the reference's marker
    names, gaps filled; ``raw_recording`` the same before gap filling.
    """

    marker_names: list[str]
    slot_labels: np.ndarray
    recording: MocapRecording
    raw_recording: MocapRecording
    gaps: list[GapInfo]
    n_tracklets: int
    n_ghost_tracklets: int
    never_seen: list[str]
    seconds: float
    warnings: list[str] = field(default_factory=list)
    tracklet_ids: np.ndarray | None = None  # (n_frames, n_slots) tracklet of each point, -1 where empty
    tracklet_labels: np.ndarray | None = None  # label index per tracklet, GHOST if rejected

    def summary(self) -> dict:
        flagged = [g for g in self.gaps if not g.filled]
        return {
            "markers": self.marker_names,
            "frames": int(self.slot_labels.shape[0]),
            "tracklets": self.n_tracklets,
            "ghost_tracklets": self.n_ghost_tracklets,
            "ghost_samples": int((self.slot_labels == GHOST).sum()),
            "gaps_filled": sum(g.filled for g in self.gaps),
            "gaps_flagged": len(flagged),
            "flagged_gaps": [
                {"marker": g.marker, "start_frame": g.start_frame, "end_frame": g.end_frame, "reason": g.reason}
                for g in flagged
            ],
            "never_seen": self.never_seen,
            "seconds": round(self.seconds, 3),
            "warnings": self.warnings,
        }


def labeling_accuracy(slot_labels: np.ndarray, truth: np.ndarray, marker_names: list[str] | None = None) -> dict:
    """Share of correctly labelled samples against ground truth (same layout as ``slot_labels``).

    A sample is one visible point in one frame (``truth != EMPTY``); it is correct when the label
    matches, ghosts counting as correct when rejected. Also reported: the share over real-marker
    samples only and the share of ghost samples rejected; with ``marker_names``, the share per marker.
    """
    if slot_labels.shape != truth.shape:
        raise ValueError(f"shapes differ: {slot_labels.shape} vs {truth.shape}")
    seen = truth != EMPTY
    correct = (slot_labels == truth) & seen
    real = truth >= 0
    ghosts = truth == GHOST
    return {
        "samples": int(seen.sum()),
        "correct_share": float(correct.sum() / max(seen.sum(), 1)),
        "marker_samples": int(real.sum()),
        "marker_correct_share": float((correct & real).sum() / max(real.sum(), 1)),
        "ghost_samples": int(ghosts.sum()),
        "ghost_rejected_share": float((correct & ghosts).sum() / max(ghosts.sum(), 1)),
        **({"per_marker": {
            name: float((correct & (truth == i)).sum() / max((truth == i).sum(), 1))
            for i, name in enumerate(marker_names)
        }} if marker_names is not None else {}),
    }


def _median_nearest_distance(pos: np.ndarray, max_frames: int = 500) -> float | None:
    """Median over frames and visible markers of the distance to the nearest other marker (metres);
    on plate-carrying recordings it is set by the plates' known spacing. None if it cannot be measured."""
    if pos.shape[0] == 0 or pos.shape[1] < 2:
        return None
    rows = pos[np.linspace(0, pos.shape[0] - 1, min(max_frames, pos.shape[0])).astype(int)]
    d = np.linalg.norm(rows[:, :, None, :] - rows[:, None, :, :], axis=3)
    idx = np.arange(pos.shape[1])
    d[:, idx, idx] = np.inf
    d[np.isnan(d)] = np.inf
    nearest = d.min(axis=2)
    nearest = nearest[np.isfinite(nearest) & (nearest > 0)]
    return float(np.median(nearest)) if nearest.size else None


class MarkerLabeler:
    """Label unnamed marker trajectories (scikit-learn style: ``fit(reference)``, ``predict(recording)``).

    Distances in metres, times in seconds. Tracking: ``track_gate`` (largest link distance),
    ``min_gate`` (smallest adaptive gate), ``max_speed`` (gate of a tracklet without velocity).
    Model: ``rigid_tol`` (plate detection), ``bin_m``/``smooth_m``/``max_distance`` (distance
    histograms), ``min_sigma`` (floor of a rigid pair's spread), ``weighted``/``weight_scale``
    (neighbours weighted by 1 / (spread + weight_scale)), ``trim`` (drop the worst neighbours),
    ``threshold_quantile``/``threshold_margin`` and ``strict_quantile`` (acceptance thresholds
    from the reference's own costs). Identification: ``window`` (frames sampled per tracklet),
    ``min_length_s`` (shorter tracklets are treated as possible ghosts), ``max_gap_s`` (motion
    continued across gaps up to this long; also the longest gap filled), ``refine_passes``,
    ``elimination_factor`` (<= 1 disables elimination).
    """

    def __init__(
        self,
        track_gate: float = 0.05,
        min_gate: float = 0.012,
        max_speed: float = 10.0,
        rigid_tol: float = 0.003,
        bin_m: float = 0.002,
        smooth_m: float = 0.004,
        max_distance: float = 6.0,
        min_sigma: float = 0.0007,
        weighted: bool = True,
        weight_scale: float = 0.02,
        trim: int = 0,
        threshold_quantile: float = 0.99,
        threshold_margin: float = 1.5,
        strict_quantile: float = 0.9,
        window: int = 10,
        min_length_s: float = 0.3,
        max_gap_s: float = 0.25,
        refine_passes: int = 3,
        elimination_factor: float = 2.0,
    ):
        self.track_gate = track_gate
        self.min_gate = min_gate
        self.max_speed = max_speed
        self.rigid_tol = rigid_tol
        self.bin_m = bin_m
        self.smooth_m = smooth_m
        self.max_distance = max_distance
        self.min_sigma = min_sigma
        self.weighted = weighted
        self.weight_scale = weight_scale
        self.trim = trim
        self.threshold_quantile = threshold_quantile
        self.threshold_margin = threshold_margin
        self.strict_quantile = strict_quantile
        self.window = window
        self.min_length_s = min_length_s
        self.max_gap_s = max_gap_s
        self.refine_passes = refine_passes
        self.elimination_factor = elimination_factor
        for name in ("track_gate", "min_gate", "max_speed", "rigid_tol", "bin_m", "max_distance", "min_sigma", "window"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if not np.isfinite(self.max_gap_s) or self.max_gap_s < 0:
            raise ValueError(f"max_gap_s must be a number of seconds >= 0, got {self.max_gap_s}")

    # ------------------------------------------------------------------ fit
    def fit(self, reference: MocapRecording) -> "MarkerLabeler":
        """Learn distances, plates and thresholds from a labelled recording."""
        pos = reference.positions
        n, m, _ = pos.shape
        if n < 2:
            raise LabelingError(f"the reference recording is too short ({n} frame(s)); it needs at least 2")
        missing = reference.missing_markers()
        if missing:
            raise LabelingError(f"reference markers never visible, cannot learn them: {missing}")
        self.marker_names_ = list(reference.marker_names)
        d = np.linalg.norm(pos[:, :, None, :] - pos[:, None, :, :], axis=3)  # (n, m, m)
        self.pair_cost_, informative, spread = self._learn_pair_costs(d)
        self._learn_rigid_pairs(d, informative, spread)
        self.plates_ = self._find_plates(spread, informative)
        self._learn_thresholds(pos, d)
        self.frequency_ = reference.frequency
        self.nearest_distance_ = _median_nearest_distance(pos)
        # Initial pose: the first reference frame with the most markers visible.
        vis = reference.visible()
        self.initial_pose_ = pos[int(np.argmax(vis.sum(axis=1)))].copy()
        return self

    def _learn_pair_costs(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per ordered label pair the cost of each distance bin (-log of the smoothed histogram of the reference's
        distances, capped at 12), whether the pair was seen together, and the robust spread of its distance (m)."""
        m = d.shape[1]
        n_bins = int(np.ceil(self.max_distance / self.bin_m)) + 1
        cost = np.zeros((m, m, n_bins))
        informative = np.zeros((m, m), dtype=bool)
        spread = np.full((m, m), np.inf)
        for i in range(m):
            for j in range(m):
                if i == j:
                    continue
                dij = d[:, i, j]
                dij = dij[~np.isnan(dij)]
                if len(dij) < 2:
                    continue
                informative[i, j] = True
                med = np.median(dij)
                spread[i, j] = 1.4826 * np.median(np.abs(dij - med))
                hist = np.bincount(np.minimum((dij / self.bin_m).astype(int), n_bins - 1), minlength=n_bins).astype(float)
                dens = gaussian_filter1d(hist, self.smooth_m / self.bin_m, mode="constant")
                dens /= dens.max()
                cost[i, j] = np.minimum(-np.log(dens + 1e-6), 12.0)
        return cost, informative, spread

    def _learn_rigid_pairs(self, d: np.ndarray, informative: np.ndarray, spread: np.ndarray) -> None:
        """Rigid pairs (plates): mean and spread of the distance for a Gaussian cost; the pairs' weights."""
        m = d.shape[1]
        mu = np.zeros((m, m))
        for i in range(m):
            for j in range(m):
                if informative[i, j]:
                    mu[i, j] = np.nanmedian(d[:, i, j])
        self.rigid_pair_ = informative & (spread < self.rigid_tol)
        self.rigid_mu_ = mu
        self.rigid_sigma_ = np.maximum(np.where(np.isfinite(spread), spread, 1.0), self.min_sigma)
        self.pair_weight_ = np.where(informative, 1.0 / (np.minimum(spread, 1.0) + self.weight_scale), 0.0)
        self.informative_ = informative
        self.spread_ = spread

    def _find_plates(self, spread: np.ndarray, informative: np.ndarray) -> list[list[int]]:
        """Rigid plates: disjoint triples whose pairwise distances barely vary, the most rigid first."""
        m = spread.shape[0]
        rigid = (spread < self.rigid_tol) & informative
        triples = [
            tri for tri in itertools.combinations(range(m), 3)
            if all(rigid[a, b] for a, b in itertools.combinations(tri, 2))
        ]
        triples.sort(key=lambda tri: max(spread[a, b] for a, b in itertools.combinations(tri, 2)))
        plates: list[list[int]] = []
        for tri in triples:  # most rigid first, disjoint
            if not any(set(tri) & set(p) for p in plates):
                plates.append(list(tri))
        return plates

    def _learn_thresholds(self, pos: np.ndarray, d: np.ndarray) -> None:
        """Per-label thresholds: how well the true markers fit their neighbours in the reference."""
        m = d.shape[1]
        frame_cost = self._frame_costs(pos, d)
        thresholds, typical, strict = np.zeros(m), np.zeros(m), np.zeros(m)
        for i in range(m):
            c = frame_cost[:, i]
            c = c[~np.isnan(c)]
            thresholds[i] = (np.quantile(c, self.threshold_quantile) if len(c) else 3.0) + self.threshold_margin
            typical[i] = np.median(c) if len(c) else 0.0
            strict[i] = np.quantile(c, self.strict_quantile) if len(c) else 2.0
        self.thresholds_ = thresholds
        self.strict_thresholds_ = strict
        self.typical_ = typical

    def _frame_costs(self, pos: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Mean pair cost of each visible marker against the other visible markers, per frame."""
        n, m, _ = pos.shape
        vis = ~np.isnan(pos).any(axis=2)
        bins = np.minimum(np.nan_to_num(d / self.bin_m).astype(int), self.pair_cost_.shape[2] - 1)
        ii, jj = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
        c = self.pair_cost_[ii[None], jj[None], bins]  # (n, m, m)
        c = self._rigid_override(c, d, self.rigid_mu_[None], self.rigid_sigma_[None], self.rigid_pair_[None])
        w = vis[:, :, None] & vis[:, None, :] & self.informative_[None]
        out = self._trimmed_mean(c, w, self.pair_weight_[None])
        out[~vis] = np.nan
        return out

    @staticmethod
    def _rigid_override(c, d, mu, sigma, rigid):
        """Rigid pairs: a Gaussian cost on the distance (finer than the histogram's bins, so
        nearly isosceles plates are told apart)."""
        with np.errstate(invalid="ignore"):
            gauss = np.minimum(0.5 * ((d - mu) / sigma) ** 2, 12.0)
        return np.where(rigid, np.where(np.isnan(gauss), c, gauss), c)

    def _trimmed_mean(self, c: np.ndarray, w: np.ndarray, pw: np.ndarray) -> np.ndarray:
        """Mean of ``c`` over the last axis where ``w``, dropping the ``trim`` worst terms when at
        least ``trim + 4`` partners are present (one odd partner, e.g. a marker on a moved
        object, does not veto a label), NaN where nothing is present."""
        cw = np.where(w, c, 0.0)
        num = cw.sum(axis=-1)
        den = w.sum(axis=-1).astype(float)
        if self.weighted:
            # Sharp (nearly rigid) neighbours count more than loose ones.
            ww = np.where(w, np.broadcast_to(pw, w.shape), 0.0)
            has = den > 0
            num = (cw * ww).sum(axis=-1)
            den = np.where(has, ww.sum(axis=-1), 0.0)
            with np.errstate(invalid="ignore", divide="ignore"):
                return np.where(has, num / np.where(den > 0, den, 1.0), np.nan)
        if self.trim > 0:
            worst = -np.sort(-cw, axis=-1)[..., : self.trim].sum(axis=-1)
            drop = den >= self.trim + 4
            num = np.where(drop, num - worst, num)
            den = np.where(drop, den - self.trim, den)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(den > 0, num / np.maximum(den, 1), np.nan)

    # ------------------------------------------------------------------ tracking
    def _track(self, pos: np.ndarray) -> tuple[np.ndarray, list[tuple[int, int]]]:
        """Tracklet id per (frame, slot) (-1 where empty) and each tracklet's (start, end) rows."""
        n, k, _ = pos.shape
        vis = ~np.isnan(pos).any(axis=2)
        tid = np.full((n, k), -1, dtype=int)
        spans: list[list[int]] = []
        last_pos: dict[int, np.ndarray] = {}
        prev_pos: dict[int, np.ndarray] = {}
        active: list[int] = []
        err2: dict[int, float] = {}
        for f in range(n):
            slots = np.nonzero(vis[f])[0]
            pts = pos[f, slots]
            matched_slots = set()
            new_active = []
            if active and len(slots):
                pred = np.array([2 * last_pos[t] - prev_pos[t] if t in prev_pos else last_pos[t] for t in active])
                # Adaptive gate: a few times the tracklet's recent prediction error (so a
                # neighbouring plate marker is not taken over when a marker vanishes); without
                # a velocity yet, allow for up to max_speed of motion.
                gate = np.array([
                    min(self.track_gate, max(self.min_gate, 4.0 * np.sqrt(err2[t]))) if t in prev_pos
                    else max(self.track_gate, self.max_speed / self.frequency_)
                    for t in active
                ])
                dist = np.linalg.norm(pred[:, None, :] - pts[None, :, :], axis=2)
                big = 1e6
                r, c = linear_sum_assignment(np.where(dist < gate[:, None], dist, big))
                for a, b in zip(r, c):
                    if dist[a, b] < gate[a]:
                        t = active[a]
                        if t in prev_pos:
                            err2[t] = 0.7 * err2[t] + 0.3 * dist[a, b] ** 2
                        tid[f, slots[b]] = t
                        prev_pos[t] = last_pos[t]
                        last_pos[t] = pts[b]
                        spans[t][1] = f + 1
                        matched_slots.add(b)
                        new_active.append(t)
            for b in range(len(slots)):
                if b not in matched_slots:
                    t = len(spans)
                    spans.append([f, f + 1])
                    err2[t] = (self.min_gate / 2) ** 2
                    tid[f, slots[b]] = t
                    last_pos[t] = pts[b]
                    new_active.append(t)
            for t in active:
                if t not in new_active:
                    last_pos.pop(t, None)
                    prev_pos.pop(t, None)
            active = new_active
        return tid, [tuple(s) for s in spans]

    # ------------------------------------------------------------------ identification
    def _geometry_cost(self, xs: np.ndarray, frames: np.ndarray, label_pos: np.ndarray) -> np.ndarray:
        """Per-label cost of a tracklet's points ``xs`` (w,3) at ``frames``: per frame the mean pair
        cost against the labelled markers visible then, median over frames (inf: no partners)."""
        m = label_pos.shape[1]
        partners = label_pos[frames]  # (w, m, 3)
        d = np.linalg.norm(partners - xs[:, None, :], axis=2)  # (w, m)
        ok = ~np.isnan(d)
        bins = np.minimum(np.nan_to_num(d / self.bin_m).astype(int), self.pair_cost_.shape[2] - 1)
        c = self.pair_cost_[:, np.arange(m)[None, :], bins]  # (L, w, m)
        c = self._rigid_override(c, d[None], self.rigid_mu_[:, None, :], self.rigid_sigma_[:, None, :], self.rigid_pair_[:, None, :])
        w = ok[None] & self.informative_[:, None, :]
        w &= ~np.eye(m, dtype=bool)[:, None, :]
        per_frame = self._trimmed_mean(c, w, self.pair_weight_[:, None, :])  # (L, w)
        den = w.sum(axis=2)
        out = np.full(m, np.inf)
        has = (den > 0).any(axis=1)
        out[has] = np.nanmedian(per_frame[has], axis=1)
        return out

    def _continuity_cost(self, label: int, rows: np.ndarray, pts: np.ndarray, label_pos: np.ndarray, dt: float) -> float:
        """How well the tracklet continues the label's motion before its start or after its end
        (squared prediction error over tolerance; inf if the label is not seen within max_gap)."""
        max_gap = int(round(self.max_gap_s / dt))
        n = len(label_pos)
        best = np.inf
        for direction in (1, -1):
            f0, x0 = (int(rows[0]), pts[0]) if direction == 1 else (int(rows[-1]), pts[-1])
            if direction == 1:
                lo = max(0, f0 - max_gap - 1)
                seen = np.nonzero(~np.isnan(label_pos[lo:f0, label, 0]))[0]
                if len(seen) == 0:
                    continue
                last = lo + int(seen[-1])
                step = -1
            else:
                hi = min(n, f0 + max_gap + 2)
                seen = np.nonzero(~np.isnan(label_pos[f0 + 1 : hi, label, 0]))[0]
                if len(seen) == 0:
                    continue
                last = f0 + 1 + int(seen[0])
                step = 1
            gap_t = abs(f0 - last) * dt
            p1 = label_pos[last, label]
            v = np.zeros(3)
            nb = last + step
            if 0 <= nb < n and not np.isnan(label_pos[nb, label, 0]):
                v = (p1 - label_pos[nb, label]) / dt  # velocity pointing towards the gap
            pred = p1 + v * gap_t
            tol = 0.01 + 0.5 * 9.81 * gap_t**2 + 0.2 * np.linalg.norm(v) * gap_t
            best = min(best, float((np.linalg.norm(x0 - pred) / tol) ** 2))
        return best

    def _check_scale(self, rec: MocapRecording, max_ratio: float = 3.0) -> None:
        """Refuse a recording whose markers lie much closer together (or farther apart) than the
        reference's: the plates' distances are known, so a 10x smaller spacing means centimetres."""
        ref = getattr(self, "nearest_distance_", None)
        got = _median_nearest_distance(rec.positions)
        if ref is None or got is None or not ref > 0 or not got > 0:
            return
        ratio = got / ref
        if 1.0 / max_ratio <= ratio <= max_ratio:
            return
        unit = {10.0: "centimetres", 1000.0: "metres", 0.001: "micrometres"}.get(float(10 ** round(np.log10(1.0 / ratio))), "another unit")
        raise LabelingError(
            f"the recording's markers lie {1.0 / ratio:.3g}x closer together than the reference's (median distance to the "
            f"nearest marker {got * 1000:.3g} mm vs {ref * 1000:.3g} mm, set by the rigid plates): the file is probably in "
            f"{unit}, not millimetres" if ratio < 1 else
            f"the recording's markers lie {ratio:.3g}x farther apart than the reference's (median distance to the nearest "
            f"marker {got * 1000:.3g} mm vs {ref * 1000:.3g} mm, set by the rigid plates): the file is probably in {unit}"
        )

    def predict(self, rec: MocapRecording, fill: bool = True) -> LabelingResult:
        """Label the unnamed trajectories of ``rec`` (any marker names; slots may be shuffled): track, seed the plates,
        decide the most certain tracklet first, refine, label the rest by elimination, fill the gaps."""
        t_start = _time.process_time()
        warnings = self._check_input(rec)
        tid, spans = self._track(rec.positions)
        s = LabelAssignment(rec.positions, tid, len(spans), len(self.marker_names_))
        min_len = int(round(self.min_length_s * rec.frequency))
        self._seed(s)
        self._decide_most_certain_first(s, min_len, rec.frequency)
        self._refine_labels(s, min_len, 1.0 / rec.frequency)
        eliminated = self._label_by_elimination(s, min_len)
        if eliminated:
            warnings.append(
                f"{eliminated} long trajectories fitted no label within its threshold and were labelled by "
                "elimination (markers moved since the reference recording?)"
            )
        return self._labeling_result(rec, s, tid, fill, warnings, t_start)

    def _check_input(self, rec: MocapRecording) -> list[str]:
        """:class:`LabelingError` for an unfitted labeler or a recording that cannot be labelled; the warnings so far."""
        if not hasattr(self, "pair_cost_"):
            raise LabelingError("the labeler is not fitted: call fit(reference) first")
        n = rec.positions.shape[0]
        if n < 2:
            raise LabelingError(f"the recording is too short to label ({n} frame(s))")
        if not rec.visible().any():
            raise LabelingError("no marker is visible in any frame of the recording: nothing to label")
        self._check_scale(rec)
        warnings: list[str] = []
        if abs(rec.frequency - self.frequency_) > 1e-6:
            warnings.append(f"frequency {rec.frequency:g} Hz differs from the reference's {self.frequency_:g} Hz")
        return warnings

    def _cost_row(self, s: LabelAssignment, t: int, min_len: int, dt: float, displace: bool = False) -> np.ndarray:
        """Per-label cost of tracklet ``t`` (lower is better), inf where the label is taken or fails its threshold;
        NaN everywhere when there is nothing to compare with yet."""
        m = len(self.marker_names_)
        rows = s.rows_of[t]
        sample = np.unique(np.linspace(0, len(rows) - 1, min(self.window, len(rows))).round().astype(int))
        geo = self._geometry_cost(s.pts_of[t][sample], rows[sample], s.label_pos)
        free = ~s.occupied[rows].any(axis=0)
        if displace:
            # A long trajectory may take over a label held only by short (ghost-like) pieces.
            own = s.owner[rows]
            if len(rows) >= min_len:
                held_by_short = np.where(own >= 0, s.lengths[np.maximum(own, 0)] < min_len, True).all(axis=0)
                free |= held_by_short
        short = len(rows) < min_len
        in_plate = np.zeros(m, dtype=bool)
        for p in self.plates_:
            in_plate[p] = True
        out = np.full(m, np.inf)
        any_evidence = False
        for lab in np.nonzero(free)[0]:
            cont = self._continuity_cost(lab, rows, s.pts_of[t], s.label_pos, dt)
            g = geo[lab]
            any_evidence |= bool(np.isfinite(g) or np.isfinite(cont))
            limit = self.strict_thresholds_[lab] if short else self.thresholds_[lab]
            if cont <= 4.0:  # continues the label's motion across a gap
                out[lab] = min(g, self.typical_[lab])
            elif g <= limit and not (short and not in_plate[lab]):
                # A short trajectory of a single (non-plate) marker must continue the
                # marker's motion: alone, such pieces are mostly ghosts.
                out[lab] = g
        if not any_evidence and free.any():
            out[:] = np.nan
        return out

    def _seed(self, s: LabelAssignment) -> None:
        """Step 1: at the frame where most long tracklets coexist, whole plates (the initial pose); then plates again
        wherever long tracklets start (re-acquisition after occlusions), so that plate members are decided jointly
        rather than one by one."""
        lengths, rows_of = s.lengths, s.rows_of
        long_ts = np.nonzero(lengths >= min(self.window, lengths.max()))[0]
        active = np.zeros(len(s.label_pos), dtype=int)
        for t in long_ts:
            active[rows_of[t][0] : rows_of[t][-1] + 1] += 1
        f_seed = int(np.argmax(active))
        seed_group = [int(t) for t in long_ts if rows_of[t][0] <= f_seed <= rows_of[t][-1]]
        self._seed_plates(seed_group, f_seed, rows_of, s.pts_of, s.label_pos, s.occupied, s.assign)
        if not s.occupied.any():
            # No plate found: fall back on the reference's initial pose.
            self._seed_initial_pose(seed_group, f_seed, rows_of, s.pts_of, s.assign)
        if self.plates_:
            for f in sorted({int(rows_of[t][0]) for t in long_ts}):
                group = [int(t) for t in long_ts if s.label_of[t] == GHOST and rows_of[t][0] <= f <= rows_of[t][-1]]
                if len(group) >= 2:
                    self._seed_plates(group, f, rows_of, s.pts_of, s.label_pos, s.occupied, s.assign)

    def _decide_most_certain_first(self, s: LabelAssignment, min_len: int, frequency: float) -> None:
        """Step 2: repeatedly assign the pending tracklet whose best label beats its runner-up (or its threshold) by
        the widest margin; decisions change the neighbours' costs, so tracklets overlapping in time are re-scored."""
        dt = 1.0 / frequency
        max_gap = int(round(self.max_gap_s * frequency))
        starts = np.array([r[0] for r in s.rows_of])
        ends = np.array([r[-1] for r in s.rows_of])
        pending = {int(t) for t in range(s.n_tracklets) if s.label_of[t] == GHOST}
        rows_cache = {t: self._cost_row(s, t, min_len, dt) for t in pending}
        margins = {t: self._margin(rows_cache[t], s.lengths[t]) for t in pending}
        while pending:
            t = max(pending, key=margins.__getitem__)
            if not np.isfinite(margins[t]):
                break
            c = rows_cache[t]
            s.assign(t, int(np.nanargmin(np.where(np.isfinite(c), c, np.inf))))
            pending.discard(t)
            near = [u for u in pending if starts[u] <= ends[t] + max_gap and ends[u] >= starts[t] - max_gap]
            for u in near:
                rows_cache[u] = self._cost_row(s, u, min_len, dt)
                margins[u] = self._margin(rows_cache[u], s.lengths[u])

    def _margin(self, c: np.ndarray, length: int) -> float:
        """How much a tracklet's best label (costs ``c``) beats its runner-up or its threshold; longer ones first on
        a tie; -inf when no label fits."""
        finite = np.sort(c[np.isfinite(c)])
        if len(finite) == 0:
            return -np.inf
        lab = int(np.nanargmin(np.where(np.isfinite(c), c, np.inf)))
        second = finite[1] if len(finite) > 1 else self.thresholds_[lab]
        return float(second - finite[0]) + 1e-3 * min(length, 1000)

    def _refine_labels(self, s: LabelAssignment, min_len: int, dt: float) -> None:
        """Step 3: re-decide every tracklet (the longest first) with all the others labelled, until nothing changes."""
        for _pass in range(self.refine_passes):
            changed = 0
            for t in np.argsort(-s.lengths, kind="stable"):
                before = s.label_of[t]
                s.unassign(t)
                costs = self._cost_row(s, t, min_len, dt, displace=True)
                if np.isfinite(costs).any():
                    s.assign(t, int(np.nanargmin(np.where(np.isnan(costs), np.inf, costs))))
                changed += int(s.label_of[t] != before)
            if changed == 0:
                break

    def _label_by_elimination(self, s: LabelAssignment, min_len: int) -> int:
        """Step 4: a long trajectory that fits no label within its threshold (e.g. a marker re-attached since the
        reference was recorded) takes the free label it fits best if that is within ``elimination_factor`` times the
        threshold. Returns how many did."""
        eliminated = 0
        if self.elimination_factor <= 1.0:
            return eliminated
        for t in np.argsort(-s.lengths, kind="stable"):
            if s.label_of[t] != GHOST or s.lengths[t] < max(min_len, 2 * self.window):
                continue
            rows = s.rows_of[t]
            sample = np.unique(np.linspace(0, len(rows) - 1, min(self.window, len(rows))).round().astype(int))
            geo = self._geometry_cost(s.pts_of[t][sample], rows[sample], s.label_pos)
            free = ~s.occupied[rows].any(axis=0)
            ratio = np.where(free, geo / self.thresholds_, np.inf)
            lab = int(np.argmin(ratio))
            if ratio[lab] <= self.elimination_factor:
                s.assign(t, lab)
                eliminated += 1
        return eliminated

    def _labeling_result(self, rec: MocapRecording, s: LabelAssignment, tid: np.ndarray, fill: bool, warnings: list[str],
                         t_start: float) -> LabelingResult:
        """The labelled recording (gaps filled with ``fill``), each slot's label and the report."""
        n, k, _ = rec.positions.shape
        slot_labels = np.full((n, k), EMPTY, dtype=int)
        has = tid >= 0
        slot_labels[has] = s.label_of[tid[has]]
        names = list(self.marker_names_)
        raw = MocapRecording(names, s.label_pos, rec.frequency, rec.frames.copy(), rec.time.copy(), dict(rec.metadata))
        never = raw.missing_markers()
        if never:
            warnings.append(f"markers never found: {never}")
        plates = [[names[i] for i in p] for p in self.plates_]
        if fill:
            filled: GapFillResult = fill_gaps(raw, self.max_gap_s, plates)
            out_rec, gaps = filled.recording, filled.gaps
        else:
            out_rec, gaps = raw, []
        return LabelingResult(
            names, slot_labels, out_rec, raw, gaps, s.n_tracklets, int((s.label_of == GHOST).sum()), never,
            _time.process_time() - t_start, warnings, tid, s.label_of,
        )

    def _seed_initial_pose(self, group, frame, rows_of, pts_of, assign, max_error: float = 0.1) -> None:
        """Match the tracklets active at ``frame`` to the reference's initial pose (both
        centred on their centroid), Hungarian on distance, matches within ``max_error`` metres."""
        if len(group) < 2:
            return
        ref = self.initial_pose_
        ok = ~np.isnan(ref).any(axis=1)
        pts = np.array([pts_of[t][int(np.searchsorted(rows_of[t], frame))] for t in group])
        if ok.sum() < 2:
            return
        ref_c = ref[ok] - ref[ok].mean(axis=0)
        pts_c = pts - pts.mean(axis=0)
        cost = np.linalg.norm(pts_c[:, None, :] - ref_c[None, :, :], axis=2)
        rows, cols = linear_sum_assignment(cost)
        labels = np.nonzero(ok)[0]
        for r, c in zip(rows, cols):
            if cost[r, c] <= max_error:
                assign(group[r], int(labels[c]))

    def _pair_cost(self, ia: int, ib: int, dd: np.ndarray) -> float:
        """Mean learned cost of distances ``dd`` between labels ``ia`` and ``ib``."""
        bins = np.minimum((dd / self.bin_m).astype(int), self.pair_cost_.shape[2] - 1)
        pc = self._rigid_override(self.pair_cost_[ia, ib, bins], dd, self.rigid_mu_[ia, ib],
                                  self.rigid_sigma_[ia, ib], self.rigid_pair_[ia, ib])
        return float(pc.mean())

    def _seed_plates(self, group, frame, rows_of, pts_of, label_pos, occupied, assign) -> None:
        """Assign the free labels of each plate (at least two free at ``frame``) jointly among the
        tracklets of ``group`` (active at ``frame``): the permutation that best fits the learned
        distances among themselves and to the plate's labelled members, over ``window`` frames."""
        def window(t):
            rows = rows_of[t]
            i = int(np.searchsorted(rows, frame))
            return rows[i : i + self.window], pts_of[t][i : i + self.window]

        win = {t: window(t) for t in group}
        for plate in self.plates_:
            free = [lab for lab in plate if not occupied[frame, lab]]
            fixed = [lab for lab in plate if occupied[frame, lab]]
            if len(free) < 2:
                continue
            cands = {lab: [t for t in group if not occupied[rows_of[t], lab].any()] for lab in free}
            pool = sorted(set().union(*cands.values()))
            best, best_cost = None, np.inf
            for perm in itertools.permutations(pool, len(free)):
                if any(t not in cands[lab] for lab, t in zip(free, perm)):
                    continue
                cost, terms = 0.0, 0
                for (ia, ta), (ib, tb) in itertools.combinations(zip(free, perm), 2):
                    (ra, xa), (rb, xb) = win[ta], win[tb]
                    common = np.intersect1d(ra, rb)
                    if len(common) == 0:
                        cost = np.inf
                        break
                    cost += self._pair_cost(ia, ib, np.linalg.norm(xa[np.searchsorted(ra, common)] - xb[np.searchsorted(rb, common)], axis=1))
                    terms += 1
                for ia, ta in zip(free, perm):
                    if not np.isfinite(cost):
                        break
                    ra, xa = win[ta]
                    for ib in fixed:
                        other = label_pos[ra, ib]
                        ok = ~np.isnan(other).any(axis=1)
                        if ok.any():
                            cost += self._pair_cost(ia, ib, np.linalg.norm(xa[ok] - other[ok], axis=1))
                            terms += 1
                cost = cost / max(terms, 1)
                if cost < best_cost:
                    best, best_cost = perm, cost
            if best is not None and best_cost <= max(self.strict_thresholds_[plate]):
                for lab, t in zip(free, best):
                    assign(t, lab)
                group = [t for t in group if t not in best]
